"""The whole suite runs with the product's pinned numeric kernels (cmrt.numerics), as every
`cmrt` process does: tests compare a run in this process (a command line's `main`) with the
same run in a server or worker process by `repr`, which holds only when both use the same
kernels. Pinned here, before any test module imports numpy."""

from cmrt.numerics import pin_numeric_kernels

NUMERICS_PINNED = pin_numeric_kernels()
