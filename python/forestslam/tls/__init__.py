"""MLS-to-TLS forest plot mapping with stem-centre and DoG features (Shao et al. 2020)."""

from forestslam.lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "config": ("TlsConfig",),
        "features": ("coarse_stem_alignment", "frame_features", "reference_stems"),
        "pipeline": ("FrameRecord", "TlsRun", "register_mls_to_tls"),
        "trees": ("PlotTrees", "circumference_coverage", "plot_trees"),
    },
)
