"""HTTP layer: the FastAPI app factory (`service.app.create_app`), schemas, dashboard page."""

from cmrt.numerics import pin_numeric_kernels

pin_numeric_kernels()  # before anything loads numpy: the same kernels on every host
