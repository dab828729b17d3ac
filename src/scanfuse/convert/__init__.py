"""Depth image to scan: the paper's row method and the height-aware obstacle method."""
