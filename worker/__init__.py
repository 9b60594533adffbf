"""Distribution layer: the job driver (ask/tell loop over the store), executors (local process
pool | Celery), the Celery app and its evaluation task. Knows nothing of HTTP.
"""
