"""The Celery application: broker, result backend and task settings from `cmrt.settings`
(the delivery guarantees below are described in docs/service.md, "Architecture").

- `task_acks_late` + `task_reject_on_worker_lost`: a message is acknowledged only after its task
  returned; if the pool process dies mid-task the message goes back to the queue.
- `worker_prefetch_multiplier = 1`: a worker process reserves one evaluation at a time, so a
  slow candidate never holds others hostage and a killed worker loses at most its own.
- `task_time_limit` (hard) and a soft limit a little earlier, both under Redis'
  `visibility_timeout` (checked in cmrt.settings), so Redis never re-delivers a message whose
  task is still running.
- Results are tiny dicts that expire after an hour; traces and trajectories go to the database.
"""

from __future__ import annotations

from celery import Celery

from cmrt.settings import Settings, get_settings

TASK_EVALUATE_BATCH = "cmrt.evaluate_candidates"


def make_celery(
    broker_url: str | None = None,
    result_backend: str | None = None,
    config: Settings | None = None,
) -> Celery:
    """A configured Celery app. Without a broker (embedded mode) it is inert ("memory://")."""
    cfg = config or get_settings()
    if broker_url is None and result_backend is None:
        broker_url, result_backend = cfg.broker_url, cfg.celery_result_backend
    app = Celery("cmrt", broker=broker_url or "memory://", backend=result_backend or None)
    soft = max(1.0, cfg.eval_time_limit - min(30.0, 0.1 * cfg.eval_time_limit))
    app.conf.update(
        task_default_queue=cfg.queue,
        task_serializer="json",
        result_serializer="json",
        accept_content=["json"],
        task_acks_late=True,
        task_reject_on_worker_lost=True,
        task_acks_on_failure_or_timeout=True,
        worker_prefetch_multiplier=1,
        task_time_limit=cfg.eval_time_limit,
        task_soft_time_limit=soft,
        # No redis-py socket_timeout here, on purpose (partition drill, tests/integration): with
        # one, an ack sent while the link is silently cut fails ("Couldn't ack") and kombu keeps
        # the message's prefetch slot, so the worker never consumes again; without one, the ack
        # waits for the link and the worker carries on once it is back.
        broker_transport_options={"visibility_timeout": cfg.visibility_timeout},
        result_backend_transport_options={"visibility_timeout": cfg.visibility_timeout},
        result_expires=3600,
        broker_connection_retry_on_startup=True,
        broker_connection_timeout=3,
        # With acks_late, tasks running when the broker connection drops are re-delivered;
        # cancel them instead of letting them run twice.
        worker_cancel_long_running_tasks_on_connection_loss=True,
        worker_max_tasks_per_child=None,
        worker_send_task_events=False,
        task_track_started=False,
        imports=("worker.tasks",),
    )
    from worker.fingerprints import FingerprintStep

    app.steps["worker"].add(FingerprintStep)  # logs and reports the numeric fingerprint
    return app


app = make_celery()
