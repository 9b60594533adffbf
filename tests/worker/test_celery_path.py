"""The Celery side of the distributed path, without a broker: task and app settings required by
docs/service.md ("Architecture"), what the driver sends, and when it polls the store."""

from __future__ import annotations

import contextlib

import pytest

from cmrt.settings import Settings
from worker.celery_app import TASK_EVALUATE_BATCH, make_celery
from worker.executors import (
    MIN_POLL_INTERVAL,
    CeleryExecutor,
    GenerationDispatch,
    PollSchedule,
    plan_batches,
)


@pytest.fixture
def config(tmp_path):
    settings = Settings(data_dir=tmp_path, database_url=f"sqlite:///{tmp_path}/t.db",
                        broker_url="redis://127.0.0.1:1/0", eval_time_limit=60,
                        visibility_timeout=120)
    return settings


def test_evaluation_task_settings() -> None:
    from worker.tasks import evaluate_candidates

    assert evaluate_candidates.name == TASK_EVALUATE_BATCH
    assert evaluate_candidates.acks_late and evaluate_candidates.reject_on_worker_lost
    assert evaluate_candidates.ignore_result  # the driver reads the store, never a result


def test_app_settings_follow_the_design(config) -> None:
    conf = make_celery("redis://127.0.0.1:1/0", "redis://127.0.0.1:1/0", config).conf
    assert conf.task_acks_late and conf.task_reject_on_worker_lost
    assert conf.worker_prefetch_multiplier == 1
    assert conf.task_soft_time_limit < conf.task_time_limit == 60
    assert conf.task_time_limit < conf.broker_transport_options["visibility_timeout"] == 120


class _RecordingApp:
    """Stands in for the Celery app: records what the executor sends."""

    def __init__(self) -> None:
        self.sent: list[tuple[str, list, dict]] = []

    def send_task(self, name, args=None, **options):
        self.sent.append((name, args, {k: v for k, v in options.items() if k != "producer"}))

    def producer_or_acquire(self, producer=None):
        return contextlib.nullcontext(producer)


def test_driver_sends_ids_only_and_asks_for_no_result(config) -> None:
    app = _RecordingApp()
    ex = CeleryExecutor(config, app)
    ex._send("job-1", 3, [[0, 2], [5]], lambda: None)
    assert [(n, a) for n, a, _ in app.sent] == [(TASK_EVALUATE_BATCH, ["job-1", 3, [0, 2]]),
                                              (TASK_EVALUATE_BATCH, ["job-1", 3, [5]])]
    for _, _, options in app.sent:
        assert options["ignore_result"] is True and options["queue"] == config.queue
    # the time limits scale with the task's candidates (60 s each, the soft one 6 s earlier)
    assert [(o["time_limit"], o["soft_time_limit"]) for _, _, o in app.sent] == [
        (120, 114), (60, 54)]
    assert (ex.sent, ex.tasks) == (3, 2)


def test_batches_shrink_to_one_candidate_per_task_at_the_end_of_a_generation() -> None:
    # a generation of 10 on 2 processes, window 4, at most 2 per task
    assert plan_batches(10, room=4, window=4, slots=2, cap=2) == [2, 2]
    assert plan_batches(6, room=2, window=4, slots=2, cap=2) == [2]
    assert plan_batches(4, room=1, window=4, slots=2, cap=2) == []  # waits for room for 2
    assert plan_batches(3, room=2, window=4, slots=2, cap=2) == [1, 1]
    assert plan_batches(1, room=4, window=4, slots=2, cap=2) == [1]
    # never fewer tasks in the window than processes; cap 1 is one task per candidate
    assert plan_batches(32, room=8, window=8, slots=2, cap=8) == [4, 4]
    assert plan_batches(32, room=4, window=4, slots=4, cap=8) == [1, 1, 1, 1]
    assert plan_batches(5, room=4, window=4, slots=2, cap=1) == [1, 1, 1, 1]


def test_a_result_announced_twice_frees_its_place_once(config) -> None:
    # a re-sent candidate is announced by both of its tasks (the second finds it stored), and
    # both notices may arrive in one read
    app = _RecordingApp()
    send = GenerationDispatch(CeleryExecutor(config, app), None, "job-1", 0, [0, 1, 2, 3],
                              lambda: None)
    send.start()
    assert sorted(send.sent_at) == [0, 1, 2, 3] and not send.unsent
    assert send.announced([2, 2, 7]) == 1  # 7: not out (resolved before, or another's)
    assert sorted(send.sent_at) == [0, 1, 3] and send.outstanding
    assert send.announced([0, 1, 3]) == 3 and not send.outstanding


def test_batch_cap_keeps_a_task_inside_the_visibility_timeout(config) -> None:
    # 60 s per candidate, Redis re-delivers after 120 s: one candidate per task at most ...
    assert CeleryExecutor(config.model_copy(update={"task_batch": 8}), _RecordingApp()
                          ).batch_cap == 1
    # ... and with room for five, five
    five = config.model_copy(update={"task_batch": 8, "visibility_timeout": 301})
    assert CeleryExecutor(five, _RecordingApp()).batch_cap == 5


def test_poll_schedule_backs_off_until_the_first_result() -> None:
    s = PollSchedule(start=0.0, longest=0.2)
    waits = [s.delay(now=0.0, resolved=0, remaining=8) for _ in range(6)]
    assert waits == [MIN_POLL_INTERVAL, 0.02, 0.04, 0.08, 0.16, 0.2]


def test_poll_schedule_closes_in_on_the_expected_end() -> None:
    s = PollSchedule(start=0.0, longest=0.2)
    # 40 ms per result: 24 left -> ~1 s to go -> the longest wait
    assert s.delay(now=0.4, resolved=10, remaining=24) == 0.2
    # 4 left -> 160 ms to go -> a quarter of it
    assert s.delay(now=1.2, resolved=30, remaining=4) == pytest.approx(0.04)
    # the last one, overdue or not: never below the shortest wait
    assert s.delay(now=2.0, resolved=33, remaining=1) == pytest.approx(2.0 / 33 / 4)
    assert s.delay(now=0.1, resolved=33, remaining=1) == MIN_POLL_INTERVAL
    # candidates of seconds: the longest wait throughout
    assert PollSchedule(0.0, 0.2).delay(now=5.0, resolved=1, remaining=1) == 0.2
    # a longest wait below the shortest one wins
    assert PollSchedule(0.0, 0.005).delay(now=0.0, resolved=0, remaining=3) == 0.005
