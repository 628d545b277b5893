"""Many captures: one task per capture on a local process pool, or Ray tasks on a cluster (``holousd batch``).

:func:`run_tasks` is the engine the benchmark harness shares (``holousd bench --ray``).
"""

from holousd._tasks import TaskOutcome, run_tasks
from holousd.batch._batch import BatchConfig, BatchResult, batch_table, run_batch

__all__ = ["BatchConfig", "BatchResult", "TaskOutcome", "batch_table", "run_batch", "run_tasks"]
