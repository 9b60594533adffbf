"""Distribution layer: the job driver (ask/tell loop over the store), executors (local process
pool | Celery), the Celery app and its evaluation task. Knows nothing of HTTP.
"""

from cmrt.numerics import pin_numeric_kernels

pin_numeric_kernels()  # before anything loads numpy: the same kernels on every host
