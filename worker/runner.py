"""Hosts job drivers in background threads of a long-running process (the API).

`JobRunner.submit(job_id)` starts a driver for a new job at once; a scanner thread looks every
`scan_interval` s for queued or running jobs without a live lease (`orphaned_jobs`: never driven,
or their driver died with its process) and drives them, and advances every unfinished family
one step (`worker.family.FamilyDriver`: its ready runs become jobs, its checks are computed).
So a restarted API resumes its running jobs from their last stored generation once their lease
has expired, and several API replicas share the jobs safely (the lease admits one driver per
job; a family's runs are created at most once).
"""

from __future__ import annotations

import logging
import threading
from typing import Any

from cmrt.settings import Settings
from store import Repository
from worker.driver import CancelFlags, JobDriver, make_owner
from worker.executors import GenerationExecutor
from worker.family import FamilyDriver

log = logging.getLogger(__name__)


class JobRunner:
    def __init__(
        self,
        repo: Repository,
        executor: GenerationExecutor,
        config: Settings,
        *,
        max_drivers: int = 32,
        family_driver: FamilyDriver | None = None,
    ) -> None:
        self.repo = repo
        self.executor = executor
        self.config = config
        self.owner = make_owner()
        self.max_drivers = max_drivers
        self.shutdown = threading.Event()
        self._lock = threading.Lock()
        self._active: dict[str, threading.Thread] = {}
        self._scanner: threading.Thread | None = None
        self.finished: dict[str, str | None] = {}
        #: One read of the cancel flags per tick for all the jobs driven here.
        self.cancels = CancelFlags(repo)
        self.families = family_driver or FamilyDriver(repo, config, submit=self.submit)

    # -- lifecycle ---------------------------------------------------------------------------
    def start(self) -> None:
        if self._scanner is None:
            self._scanner = threading.Thread(target=self._scan_loop, name="job-scanner",
                                             daemon=True)
            self._scanner.start()

    def stop(self, timeout: float = 10.0) -> None:
        """Stop scanning and ask drivers to stop after their current poll (their jobs stay
        `running` and are resumed by the next runner once the lease expires)."""
        self.shutdown.set()
        if self._scanner is not None:
            self._scanner.join(timeout=timeout)
        for t in list(self._active.values()):
            t.join(timeout=timeout)
        self.families.close()

    # -- drivers -----------------------------------------------------------------------------
    def submit(self, job_id: str) -> bool:
        """Start a driver thread for the job unless one runs here already."""
        with self._lock:
            if self.shutdown.is_set() or job_id in self._active:
                return False
            if len(self._active) >= self.max_drivers:
                return False  # the scanner will pick it up later
            t = threading.Thread(target=self._drive, args=(job_id,), name=f"driver-{job_id[:8]}",
                                 daemon=True)
            self._active[job_id] = t
        t.start()
        return True

    def _drive(self, job_id: str) -> None:
        try:
            driver = JobDriver(self.repo, job_id, self.executor, self.config, owner=self.owner,
                               shutdown=self.shutdown, cancels=self.cancels)
            self.finished[job_id] = driver.run()
        except Exception:  # noqa: BLE001
            log.exception("job %s: driver thread crashed", job_id)
        finally:
            with self._lock:
                self._active.pop(job_id, None)

    def _scan_loop(self) -> None:
        while not self.shutdown.is_set():
            try:
                for job in self.repo.orphaned_jobs(limit=self.max_drivers):
                    self.submit(job.id)
            except Exception as err:  # noqa: BLE001 - database down: try again next round
                log.warning("job scan failed: %s", err)
            self.advance_families()
            self.shutdown.wait(self.config.scan_interval)

    def advance_families(self) -> None:
        """One step of every unfinished family (a family's error is logged, never raised:
        the next scan tries again)."""
        try:
            active = self.repo.active_families()
        except Exception as err:  # noqa: BLE001 - database down: try again next round
            log.warning("family scan failed: %s", err)
            return
        for fam in active:
            if self.shutdown.is_set():
                return
            try:
                self.families.advance(fam.id)
            except Exception:  # noqa: BLE001
                log.exception("family %s: step failed; retried next scan", fam.id)

    @property
    def active(self) -> list[str]:
        with self._lock:
            return list(self._active)

    def stats(self) -> dict[str, Any]:
        return {"owner": self.owner, "active_drivers": len(self._active),
                "executor": self.executor.kind, **self.executor.stats()}
