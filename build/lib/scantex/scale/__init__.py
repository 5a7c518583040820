"""Beyond one scan at a time: many scans as a batch, and one huge scan as overlapping tiles.

Both run their jobs on a local process pool (the default) or as Ray tasks on a cluster
(:mod:`scantex.scale.executors`); Ray is an optional extra (``pip install 'scantex[ray]'``).
"""

from scantex.scale.batch import BatchResult, batch
from scantex.scale.executors import Job, LocalPool, RayCluster, WorkerLost
from scantex.scale.inputs import ScanInput, collect_inputs

__all__ = ["BatchResult", "Job", "LocalPool", "RayCluster", "ScanInput", "WorkerLost", "batch", "collect_inputs"]
