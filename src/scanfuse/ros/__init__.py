"""ROS-shaped edges of scanfuse: messages, time pairing, TF and recorded bags (via rosbags)."""

from scanfuse.frames import StampedTransform, TransformStore
from scanfuse.ros.bag import BagReport, Storage, TopicChoice, fuse_bag
from scanfuse.ros.calibration import BagCalibration, calibrate_bag
from scanfuse.ros.messages import (
    DepthImage,
    Distro,
    typestore,
)

__all__ = [
    'BagCalibration',
    'BagReport',
    'DepthImage',
    'Distro',
    'StampedTransform',
    'Storage',
    'TopicChoice',
    'TransformStore',
    'calibrate_bag',
    'fuse_bag',
    'typestore',
]
