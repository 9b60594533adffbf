"""`cmrt`'s one mapping of refusals to exit statuses (cli.main.main): an application error
ends the command with its class's exit status and its message on stderr."""

from __future__ import annotations

import argparse

import pytest

from application.errors import Busy, InvalidRequest, Missing
from cli import main as cli_main


@pytest.mark.parametrize(("err", "code"), [
    (InvalidRequest("spec: required"), 2),
    (Missing("family: no library CMRTs of family 'x'"), 2),
    (Busy("verify: every simulation process is busy; retry later", 5), 75),
])
def test_an_application_error_ends_with_its_exit_status(monkeypatch, capsys, err, code):
    def refuse(args: argparse.Namespace) -> int:
        raise err

    parser = cli_main.build_parser()
    monkeypatch.setattr(cli_main, "build_parser", lambda: parser)
    monkeypatch.setattr(parser, "parse_args",
                        lambda argv=None: argparse.Namespace(func=refuse, command="x"))
    assert cli_main.main([]) == code
    assert capsys.readouterr().err == f"cmrt: error: {err.message}\n"
