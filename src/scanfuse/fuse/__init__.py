"""Bring a depth scan onto the LiDAR's grid and merge the two."""

from scanfuse.fuse.merge import merge_scans
from scanfuse.fuse.resample import resample, resample_conservative, resample_linear

__all__ = ['merge_scans', 'resample', 'resample_conservative', 'resample_linear']
