"""ROS-shaped edges of scanfuse: messages, time pairing, TF and recorded bags (via rosbags)."""

from scanfuse.frames import StampedTransform, TransformStore
from scanfuse.ros.bag import BagReport, Storage, TopicChoice, fuse_bag
from scanfuse.ros.messages import (
    DepthImage,
    Distro,
    typestore,
)

__all__ = [
    'BagReport',
    'DepthImage',
    'Distro',
    'StampedTransform',
    'Storage',
    'TopicChoice',
    'TransformStore',
    'fuse_bag',
    'typestore',
]
