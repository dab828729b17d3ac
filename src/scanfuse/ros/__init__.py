"""ROS-shaped edges of scanfuse: messages, time pairing, TF and recorded bags (via rosbags)."""

from scanfuse.ros.bag import BagReport, Storage, TopicChoice, fuse_bag
from scanfuse.ros.messages import DepthImage, Distro, StampedTransform, typestore
from scanfuse.ros.sync import Pair, StreamPairer, pair_nearest
from scanfuse.ros.tf import TransformStore

__all__ = [
    'BagReport',
    'DepthImage',
    'Distro',
    'Pair',
    'StampedTransform',
    'Storage',
    'StreamPairer',
    'TopicChoice',
    'TransformStore',
    'fuse_bag',
    'pair_nearest',
    'typestore',
]
