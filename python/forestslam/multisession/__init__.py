"""One map across sessions: merging tree maps of two runs (and, later, prior maps in a run)."""

from forestslam.multisession.merge import MapAlignment, MergeConfig, align_tree_maps, fuse_trees

__all__ = ["MapAlignment", "MergeConfig", "align_tree_maps", "fuse_trees"]
