"""The `cmrt` command line (`cli.main:main`): the top of the house; it imports every layer and
nothing imports it (the `python -m service` / `python -m worker` entry points run
`service.command` / `worker.command`, which `cmrt serve` / `cmrt worker` register)."""
