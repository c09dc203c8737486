"""MLS-to-TLS forest plot mapping with stem-centre and DoG features (Shao et al. 2020)."""

from forestslam.tls.config import TlsConfig
from forestslam.tls.features import coarse_stem_alignment, frame_features, reference_stems
from forestslam.tls.pipeline import FrameRecord, TlsRun, register_mls_to_tls
from forestslam.tls.trees import PlotTrees, circumference_coverage, plot_trees

__all__ = [
    "FrameRecord",
    "PlotTrees",
    "TlsConfig",
    "TlsRun",
    "circumference_coverage",
    "coarse_stem_alignment",
    "frame_features",
    "plot_trees",
    "reference_stems",
    "register_mls_to_tls",
]
