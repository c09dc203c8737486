"""One map across sessions: merging tree maps of two runs (and, later, prior maps in a run)."""

from forestslam.lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "merge": ("MapAlignment", "MergeConfig", "align_tree_maps", "fuse_trees"),
    },
)
