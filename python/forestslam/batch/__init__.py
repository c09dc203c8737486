"""Batch processing and evaluation of many recordings on Dask (`forestslam batch`)."""

from forestslam.batch.engine import BatchResult, run_batch
from forestslam.batch.manifest import Recording, load_manifest

__all__ = ["BatchResult", "Recording", "load_manifest", "run_batch"]
