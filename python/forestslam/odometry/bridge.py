"""Moved to forestslam.core_bridge (the one config bridge, shared by every component); kept as
an import path for the odometry and perception modules."""

from forestslam.core_bridge import fill_core

__all__ = ["fill_core"]
