"""The `cmrt` command line (`cli.main:main`): the top of the house; it imports every layer and
nothing imports it (the `python -m service` / `python -m worker` entry points run
`service.command` / `worker.command`, which `cmrt serve` / `cmrt worker` register)."""

from cmrt.numerics import pin_numeric_kernels

pin_numeric_kernels()  # before anything loads numpy: the same kernels on every host
