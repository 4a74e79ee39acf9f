"""``dask worker --preload`` module for the cluster test: the worker kills its own process group after N tasks of a step.

Environment: ``PATCHCLOUD_KILL_STEP`` (the step's name in the task keys,
e.g. ``fit``) and ``PATCHCLOUD_KILL_AFTER`` (N).  Without them it does
nothing.  The worker and its nanny share a process group (the test starts
each ``dask worker`` in a session of its own), so both die, as when a
machine is lost.
"""

import os
import signal

from distributed.diagnostics.plugin import WorkerPlugin


class KillAfter(WorkerPlugin):
    def __init__(self, step: str, after: int) -> None:
        self.prefix = f"patchcloud-{step}-"
        self.after = after
        self.done = 0

    def transition(self, key, start, finish, **kwargs):
        if finish == "memory" and str(key).startswith(self.prefix):
            self.done += 1
            if self.done >= self.after:
                with open(os.environ["PATCHCLOUD_KILL_MARK"], "w") as f:
                    f.write(f"{key}\n")
                os.killpg(os.getpgid(0), signal.SIGKILL)


async def dask_setup(worker):
    step, after = os.environ.get("PATCHCLOUD_KILL_STEP"), os.environ.get("PATCHCLOUD_KILL_AFTER")
    if step and after:
        await worker.plugin_add(KillAfter(step, int(after)), name="patchcloud-kill-after")
