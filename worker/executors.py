"""How a job driver gets one generation evaluated. Both executors work on the store: the
candidates are already stored as pending evaluations (keyed by job, generation, index) and the
executor returns once every one of them is resolved (done or failed).

- `LocalPoolExecutor` (embedded default, no broker): `worker.candidates.run_candidates` (the
  Celery task's own function: claim, attempts, fail, record) with the evaluations in this
  process' `FairPool` (worker.fairpool: round robin between jobs, a stopped job's running
  candidates dropped), so a candidate that kills its pool process fails its job after
  `max_attempts`; attempts cut short by a graceful stop (shutdown) are given back
  (`release_attempt`). A generation's certain last candidate stops early (`optim.rankcut`),
  as on the command line.
- `CeleryExecutor`: sends the pending candidates as `evaluate_candidates(job_id, generation,
  indices)` tasks of a few candidates each (`plan_batches`) and waits by polling the store's
  counts (never `.get()`); lost messages are sent again (idempotent, see
  `CeleryExecutor.evaluate`), so a message lost with a broker restart or a killed worker never
  hangs a job; if the broker stays unreachable for `broker_deadline` s the job fails with a
  clear error. No candidate is cut early here: the bound would have to reach a simulation
  running in another machine's worker process, mid-run (docs/architecture.md).
"""

from __future__ import annotations

import logging
import socket
import threading
import time
from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Callable, Sequence
from typing import Any

from cmrt.settings import Settings
from store import EvaluationRecord, Repository
from store.records import DONE, PENDING
from worker.candidates import (
    JobCancelledError,
    JobFailedError,
    JobSpecs,
    run_candidates,
)
from worker.fairpool import POLL_S, FairPool
from worker.notify import FALLBACK_POLL_S, NoticeWaiter

#: While the workers' notices announce every result, the driver still reads the store this
#: often, s: it finds a result whose notice was lost within this time, and an overdue candidate.
STORE_READ_S = 2.0

log = logging.getLogger(__name__)


#: Called by executors while they wait: raises DriverInterruptError when the driver must stop.
InterruptCheck = Callable[[], None]


class GenerationExecutor(ABC):
    #: Short name shown by /health and the job's details.
    kind: str = "?"

    @abstractmethod
    def evaluate(
        self,
        repo: Repository,
        job_id: str,
        generation: int,
        population: int,
        check: InterruptCheck,
        cut_margin: float | None = None,
    ) -> list[EvaluationRecord]:
        """Resolve every pending evaluation of (job, generation); return them in index order.
        `cut_margin` (`optim.rankcut.cut_margin`; None: no cut) lets the generation's certain
        last candidate stop early where the executor can (the run stays identical)."""

    def stats(self) -> dict[str, Any]:
        return {}

    def close(self) -> None:  # noqa: B027
        pass


class LocalPoolExecutor(GenerationExecutor):
    """Evaluates in this process' `FairPool` (fair share between jobs; a cancelled or stopped
    job's running candidates are dropped within `fairpool.POLL_S`)."""

    kind = "local-pool"

    def __init__(self, config: Settings) -> None:
        self.config = config
        self.pool = FairPool(config.workers, time_limit=config.eval_time_limit)
        self.cache = JobSpecs()
        self.node = f"{socket.gethostname()}/local-pool"

    def evaluate(self, repo, job_id, generation, population, check, cut_margin=None):
        """Rounds of `run_candidates` over the pending candidates until none is left (a
        candidate whose process died stays pending and is claimed again, its attempts counted).
        The cut needs every other candidate's value: the stored ones are passed along."""
        while True:
            check()
            rows = repo.evaluations(job_id, generation, params=False)
            pending = [r.index for r in rows if r.status == PENDING]
            if not pending:
                return rows
            done = [float(r.objective) for r in rows if r.status == DONE]
            margin = cut_margin if len(done) + len(pending) == population else None

            def pool_run(fn, xs, on_result, done=done, margin=margin):
                self.pool.run(job_id, fn, xs, check, on_result, cut_margin=margin, done=done)

            out = run_candidates(repo, job_id, generation, pending,
                                 max_attempts=self.config.max_attempts, cache=self.cache,
                                 pool_run=pool_run, worker_name=self.node)
            if all(r["status"] == "skipped" for r in out):  # the job ended meanwhile
                time.sleep(POLL_S)  # until the driver's interrupt check reads why

    def stats(self):
        return {"workers": self.pool.workers}

    def close(self):
        self.pool.close()


#: Shortest wait between two polls of the store's counts (see `PollSchedule`).
MIN_POLL_INTERVAL = 0.01


class PollSchedule:
    """How long the driver waits before polling a generation's counts again.

    At most `longest` (CMRT_POLL_INTERVAL), which bounds the polling load while the end of the
    generation is far, and at least `shortest`. Before the first result: `shortest`, doubling
    after every poll (a generation of short candidates is closed soon after it ends). After
    that: a quarter of the expected time to the end, estimated from the rate of results since
    `start` (`remaining * elapsed / resolved`), so polls come closer together as the last
    results are due. With candidates of seconds this is `longest` after the first few polls;
    with short clips (tens of ms) it costs a handful of extra polls per generation and closes
    the generation a few ms after its last result instead of up to `longest` after it.
    """

    def __init__(self, start: float, longest: float, shortest: float = MIN_POLL_INTERVAL):
        self.start = start
        self.longest = longest
        self.shortest = min(shortest, longest)
        self._backoff = self.shortest

    def delay(self, now: float, resolved: int, remaining: int) -> float:
        """The wait after a poll at `now` that found `resolved` results since `start` and
        `remaining` evaluations unresolved."""
        if resolved <= 0 or remaining <= 0:
            wait, self._backoff = self._backoff, min(2.0 * self._backoff, self.longest)
            return wait
        eta = remaining * max(now - self.start, 0.0) / resolved
        return min(self.longest, max(self.shortest, eta / 4.0))


def _broker_errors() -> tuple[type[BaseException], ...]:
    from kombu.exceptions import OperationalError

    errs: list[type[BaseException]] = [OperationalError, ConnectionError, OSError, TimeoutError]
    try:
        import redis.exceptions as rex

        errs += [rex.ConnectionError, rex.TimeoutError]
    except ImportError:  # pragma: no cover
        pass
    return tuple(errs)


def plan_batches(unsent: int, room: int, window: int, slots: int, cap: int) -> list[int]:
    """Sizes of the tasks to send now for `unsent` candidates with `room` places left in the
    job's dispatch window (`window` in all), for `slots` evaluation processes, at most `cap`
    candidates per task.

    A task carries `min(cap, window // slots, unsent // slots)` candidates (at least one):
    never so many that the window holds fewer tasks than there are processes (each would wait
    for the others' candidates), and fewer as the generation runs out, so its last candidates
    go one per task and the processes finish together (a generation of 10 on 2 processes with
    cap 2 and window 4: 2, 2, 2, 2, 1, 1). A task is sent only once the window has room for all
    of it, except a single candidate: the processes stay busy on the rest of the window
    meanwhile.
    """
    sizes: list[int] = []
    slots = max(1, slots)
    while unsent > 0 and room > 0:
        size = max(1, min(cap, window // slots, unsent // slots))
        if size > room:
            break
        sizes.append(size)
        unsent -= size
        room -= size
    return sizes


class CeleryExecutor(GenerationExecutor):
    """Sends a generation's pending candidates as `evaluate_candidates` tasks (a few candidates
    each, `plan_batches`) and waits for their results: blocked on the job's result notices
    (worker.notify) when the broker is Redis, reading the store when one arrives and at least
    every `notify.FALLBACK_POLL_S` s; polling the store (`PollSchedule`) otherwise. One
    generation's sending is a `GenerationDispatch`, its waiting a `ResultWait`."""

    kind = "celery"

    def __init__(self, config: Settings, app: Any | None = None) -> None:
        if app is None:
            from worker.celery_app import app as default_app

            app = default_app
        self.config = config
        self.app = app
        self.sent = 0
        self.tasks = 0
        self.resent = 0
        self.revoked = 0
        self._errors = _broker_errors()
        self._lock = threading.Lock()
        self._last_progress = time.monotonic()
        self._waiter = NoticeWaiter(config.broker_url if app is not None else None)

    @property
    def batch_cap(self) -> int:
        """Most candidates per task: CMRT_TASK_BATCH, and few enough that a task of them all at
        their time limit ends before Redis would re-deliver its message."""
        by_limit = int((self.config.visibility_timeout - 1e-9) // self.config.eval_time_limit)
        return max(1, min(self.config.task_batch, by_limit))

    # -- broker ------------------------------------------------------------------------------
    def _send(
        self, job_id: str, generation: int, batches: Sequence[Sequence[int]],
        check: InterruptCheck,
    ) -> dict[int, str]:
        """One `evaluate_candidates` task per batch of indices, with the time limits of its
        length (`eval_time_limit` per candidate); returns the Celery task id of each index
        sent (what a cancel revokes)."""
        from worker.celery_app import TASK_EVALUATE_BATCH

        pending = [list(map(int, b)) for b in batches if len(b)]
        task_ids: dict[int, str] = {}
        down_since: float | None = None
        delay = 0.2
        limit = self.config.eval_time_limit
        soft = max(1.0, limit - min(30.0, 0.1 * limit))
        while pending:
            try:
                # one producer (and broker connection) out of Celery's pool for all the tasks
                # of this call, not one acquired and released per task
                with self.app.producer_or_acquire() as producer:
                    while pending:
                        batch = pending[0]
                        n = len(batch)
                        args = [job_id, generation, batch]
                        res = self.app.send_task(
                            TASK_EVALUATE_BATCH,
                            args=args,
                            # the message's printable copy of the arguments, made here in a
                            # few µs instead of by Celery's generic saferepr
                            argsrepr=repr(args),
                            kwargsrepr="{}",
                            queue=self.config.queue,
                            retry=False,
                            # the store has the result: no result-backend subscription per
                            # task here, no result written by the worker
                            ignore_result=True,
                            time_limit=n * limit,
                            soft_time_limit=(n - 1) * limit + soft,
                            producer=producer,
                        )
                        pending.pop(0)
                        self.sent += n
                        self.tasks += 1
                        if res is not None and res.id:
                            task_ids.update(dict.fromkeys(batch, res.id))
                        down_since, delay = None, 0.2
            except self._errors as err:
                now = time.monotonic()
                down_since = down_since or now
                if now - down_since > self.config.broker_deadline:
                    raise JobFailedError(
                        f"the broker has been unreachable for {now - down_since:.0f} s "
                        f"(deadline CMRT_BROKER_DEADLINE = {self.config.broker_deadline:g} s): "
                        f"{type(err).__name__}: {err}"
                    ) from None
                log.warning("job %s: broker unreachable (%s); retrying", job_id, err)
                check()
                time.sleep(delay)
                delay = min(delay * 2, 5.0)
        return task_ids

    def ping(self, timeout: float = 2.0) -> None:
        """Raise if the broker cannot be reached."""
        with self.app.connection_for_write() as conn:
            conn.ensure_connection(max_retries=1, timeout=timeout)

    # -- generation ----------------------------------------------------------------------------
    def _progress(self) -> None:
        """An evaluation of a job driven here finished (what the stall timeout measures from)."""
        with self._lock:
            self._last_progress = time.monotonic()

    @property
    def last_progress(self) -> float:
        """When an evaluation of a job driven here last finished (monotonic clock)."""
        with self._lock:
            return self._last_progress

    def evaluate(self, repo, job_id, generation, population, check, cut_margin=None):
        """Send the unresolved candidates, at most `dispatch_window` unresolved at a time (so
        jobs share the queue fairly), and wait for the store to hold all their results.

        Sending (`GenerationDispatch`): lost messages are sent again (idempotent tasks) in two
        cases: (1) stall: no evaluation of any job driven here finished for `stall_timeout` s
        (so workers are idle or gone while this generation is unresolved: the queue lost its
        messages, e.g. a broker restart without persistence, or a worker died with them);
        (2) overdue: a candidate is unresolved `visibility_timeout + eval_time_limit` s after
        it was sent, by which time Redis would have re-delivered an unacknowledged message
        anyway. On cancel the sent evaluations are revoked before the interrupt propagates.

        Waiting (`ResultWait`): a notice names a resolved candidate (the worker sends it after
        the store has the result), so it frees its place in the window at once; the store is
        read when the notices say that every candidate is resolved (the rows, which are the
        answer when they agree), and at least every `STORE_READ_S` s (a count). A read that
        finds a result no notice announced (notices lost, or not sent) turns the rest of the
        generation to reading the store after every wait, each wait ending after
        `PollSchedule`'s delay or at the next notice. The driver's
        interrupt check (cancel flag, lease, shutdown) runs at least every `FALLBACK_POLL_S` s.
        """
        pending = repo.pending_indices(job_id, generation)  # the first read of the store
        if not pending:
            return repo.evaluations(job_id, generation, params=False)
        send = GenerationDispatch(self, repo, job_id, generation, pending, check)
        wait = ResultWait(self._waiter, job_id, generation, population,
                          resolved=population - len(pending),
                          poll_interval=self.config.poll_interval)
        try:
            send.start()
            while True:
                now = time.monotonic()
                if wait.store_due(now):
                    # the rows (the driver has their params: not read back) once the notices
                    # say all are resolved, else the counts
                    rows = (None if send.outstanding
                            else repo.evaluations(job_id, generation, params=False))
                    resolved = (repo.evaluation_counts(job_id, generation).resolved
                                if rows is None else sum(r.status != PENDING for r in rows))
                    if resolved >= population:
                        if resolved > wait.resolved:
                            self._progress()
                        return (rows if rows is not None
                                else repo.evaluations(job_id, generation, params=False))
                    unresolved: set[int] | None = None
                    if wait.unannounced(resolved):
                        self._progress()
                        unresolved = send.forget_resolved()
                    send.resend_lost(now, self.last_progress, unresolved)
                check()
                announced = wait.next()
                if announced is None:  # no notices here: the store is read next
                    continue
                if done := send.announced(announced):
                    wait.resolved += done
                    self._progress()
                    send.top_up()
                wait.after_notices(outstanding=send.outstanding)
        except JobCancelledError:
            send.revoke()
            raise
        finally:
            self._waiter.discard(job_id)

    def stats(self):
        return {"sent": self.sent, "tasks": self.tasks, "resent": self.resent,
                "revoked": self.revoked}


class GenerationDispatch:
    """What one generation of a `CeleryExecutor` has sent: the dispatch window (at most
    `dispatch_window` candidates sent and unresolved, in tasks of `plan_batches`), the
    re-sends of lost messages, and the revoke of what is out when the job is cancelled."""

    def __init__(self, executor: CeleryExecutor, repo: Repository, job_id: str,
                 generation: int, pending: Sequence[int], check: InterruptCheck) -> None:
        config = executor.config
        self.executor, self.repo, self.job_id, self.generation, self.check = (
            executor, repo, job_id, generation, check)
        self.window, self.cap = config.dispatch_window, executor.batch_cap
        # the evaluation processes are not known here: the window is sized at about twice
        # their number (docs/service.md), so batches never leave one of them without a task
        self.slots = max(1, self.window // 2)
        self.overdue_after = config.visibility_timeout + config.eval_time_limit
        self.stall_timeout = config.stall_timeout
        self.unsent = deque(pending)
        self.sent_at: dict[int, float] = {}  # sent, not seen resolved yet
        #: Celery task id of each index sent: what a cancel revokes.
        self.task_ids: dict[int, str] = {}
        self.last_send = time.monotonic()

    @property
    def outstanding(self) -> bool:
        """Whether a candidate is still out or not sent yet."""
        return bool(self.sent_at or self.unsent)

    def start(self) -> None:
        """Fill the window."""
        self.top_up()
        self.last_send = time.monotonic()

    def top_up(self) -> None:
        """Send what the window has room for."""
        sizes = plan_batches(len(self.unsent), self.window - len(self.sent_at), self.window,
                             self.slots, self.cap)
        batches = [[self.unsent.popleft() for _ in range(n)] for n in sizes]
        if batches:
            self._send(batches)
            now = time.monotonic()
            for b in batches:
                self.sent_at.update(dict.fromkeys(b, now))

    def _send(self, batches: list[list[int]]) -> None:
        self.task_ids.update(self.executor._send(self.job_id, self.generation, batches,
                                                 self.check))

    def announced(self, indices: Sequence[int]) -> int:
        """Free the places of the candidates whose results were announced; how many of them
        were out."""
        done = [i for i in dict.fromkeys(indices) if i in self.sent_at]
        for i in done:
            del self.sent_at[i]
        return len(done)

    def unresolved(self) -> set[int]:
        """The generation's candidates the store still has pending."""
        return set(self.repo.pending_indices(self.job_id, self.generation))

    def forget_resolved(self) -> set[int]:
        """Keep only the candidates the store has unresolved, fill the window; returns them."""
        unresolved = self.unresolved()
        for i in [i for i in self.sent_at if i not in unresolved]:
            del self.sent_at[i]
        self.unsent = deque(i for i in self.unsent if i in unresolved)
        self.top_up()
        return unresolved

    def resend_lost(self, now: float, last_progress: float,
                    unresolved: set[int] | None = None) -> None:
        """Send again what looks lost: every candidate out once nothing finished for
        `stall_timeout` s (since `last_progress` or the last send), else the overdue ones.
        `unresolved`: the store's pending candidates if just read (else read here if needed)."""
        quiet = now - max(last_progress, self.last_send)
        overdue = [i for i, t in self.sent_at.items() if now - t > self.overdue_after]
        if quiet <= self.stall_timeout and not overdue:
            return
        still = self.unresolved() if unresolved is None else unresolved
        again = sorted(set(self.sent_at).intersection(still) if not overdue
                       else still.intersection(overdue))
        if again:
            log.warning("job %s generation %d: %s; sending %d unresolved evaluations again",
                        self.job_id, self.generation,
                        f"no evaluation finished for {quiet:.0f} s" if not overdue
                        else f"{len(overdue)} overdue", len(again))
            self._send([[i] for i in again])
            self.executor.resent += len(again)
        self.last_send = time.monotonic()
        self.sent_at.update(dict.fromkeys(again, self.last_send))
        for i in [i for i in self.sent_at if i not in still]:
            del self.sent_at[i]

    def revoke(self) -> None:
        """Drop a cancelled job's sent evaluations: revoke their messages (a worker discards
        them unstarted) and kill the worker processes running them (`terminate`, SIGKILL)."""
        ids = self.task_ids
        task_ids = sorted({ids[i] for i in self.sent_at if i in ids})
        if not task_ids:
            return
        # every candidate those tasks carry (a batch's finished ones are resolved already)
        dropped = sum(1 for t in ids.values() if t in task_ids)
        executor = self.executor
        try:
            executor.app.control.revoke(task_ids, terminate=True, signal="SIGKILL")
            executor.revoked += dropped
            log.info("job %s: revoked %d evaluations (%d tasks) of generation %d", self.job_id,
                     dropped, len(task_ids), self.generation)
        except executor._errors as err:  # the claims skip them anyway (the job is terminal)
            log.warning("job %s: could not revoke its evaluations: %s", self.job_id, err)


class ResultWait:
    """How a `CeleryExecutor` waits for one generation's results: on the job's result notices
    while they are trusted (the store read at least every `STORE_READ_S` s, and when the
    notices say all is resolved), else reading the store after every wait (`PollSchedule`)."""

    def __init__(self, notices: NoticeWaiter, job_id: str, generation: int, population: int,
                 *, resolved: int, poll_interval: float) -> None:
        self.notices, self.job_id, self.generation = notices, job_id, generation
        self.population = population
        self.schedule = PollSchedule(time.monotonic(), poll_interval)
        #: Results known: in the store before this wait, announced, or counted in the store.
        self.resolved = self.initially = resolved
        # the caller has just read the store (the pending candidates): next read when due
        self.read_store, self.last_read = False, time.monotonic()
        self.trusted = True  # until the store holds a result no notice announced

    def store_due(self, now: float) -> bool:
        """Whether the store is to be read now (then it counts as read)."""
        if self.read_store or now - self.last_read >= (STORE_READ_S if self.trusted else 0.0):
            self.last_read = now
            return True
        return False

    def unannounced(self, resolved: int) -> bool:
        """Whether the store's count `resolved` holds results no notice announced: then the
        notices are not trusted for the rest of the generation."""
        if resolved <= self.resolved:
            return False
        self.trusted = False
        self.resolved = resolved
        return True

    def next(self) -> list[int] | None:
        """Wait for notices: the indices of this generation announced ([] on a timeout), or
        None if there are no notices here (after sleeping the poll schedule's delay)."""
        wait = self.schedule.delay(time.monotonic(), self.resolved - self.initially,
                                   self.population - self.resolved)
        notes = self.notices.wait(self.job_id, FALLBACK_POLL_S if self.trusted else wait)
        if notes is None:
            time.sleep(wait)
            self.read_store = True
            return None
        return [i for g, i in notes if g == self.generation]

    def after_notices(self, *, outstanding: bool) -> None:
        """Read the store next if the notices are not trusted or announced the last result."""
        self.read_store = not self.trusted or not outstanding


def make_generation_executor(settings: Settings) -> GenerationExecutor:
    """The executor the settings select: Celery when a broker is configured, else the local
    process pool (embedded default)."""
    if settings.distributed:
        from worker.celery_app import make_celery

        app = make_celery(settings.broker_url, settings.celery_result_backend, settings)
        return CeleryExecutor(settings, app)
    return LocalPoolExecutor(settings)
