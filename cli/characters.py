"""`cmrt characters list | add FILE --name N | show N`: character definitions kept by a
running service (POST/GET /characters, docs/characters.md), for specs to name as their
`character.model`. Exit statuses as the other client commands (cli/remote.py)."""

from __future__ import annotations

import argparse
import json
from typing import Any

from cli.remote import _client, _guard, _url_arg


def _row(name: str, source: str, s: dict[str, Any]) -> str:
    hands = ",".join(s["hands"]) or "-"
    return (f"{name[:24]:<24}  {source:<7}  {s['height']:>6.3f}  {s['mass']:>7.2f}  "
            f"{s['segments']:>8}  {len(s['joints']):>6}  {s['torso'] or '-':<10}  {hands}")


HEADER = (f"{'name':<24}  {'source':<7}  {'height':>6}  {'mass':>7}  {'segments':>8}  "
          f"{'joints':>6}  {'torso':<10}  hands")


@_guard
def cmd_characters(args: argparse.Namespace) -> int:
    """list: the stored characters and the shipped ones' names; add: keep a definition file
    under a name; show: one character's summary (its definition with --json)."""
    with _client(args) as client:
        if args.characters_command == "add":
            out = client.add_character(args.name, args.file)
            print(json.dumps(out) if args.json else
                  f"character {out['name']} stored: {out['url']}; a spec names it as "
                  f"`character: {{model: {out['name']}}}`")
        elif args.characters_command == "show":
            out = client.character(args.name)
            print(json.dumps(out) if args.json else
                  HEADER + "\n" + _row(out["name"], out["source"], out["summary"]))
        else:
            page = client.characters(limit=args.limit)
            if args.json:
                print(json.dumps(page))
                return 0
            print(HEADER)
            for c in page["items"]:
                print(_row(c["name"], c["source"], c["summary"]))
            print(f"{page['total']} stored; shipped: {', '.join(page['shipped'])}")
        return 0


def add_parsers(sub: Any) -> None:
    """Add `characters` to the `cmrt` subcommands."""
    c = sub.add_parser("characters", help="character definitions kept by the service",
                       description="Characters a running service keeps by name (POST "
                       "/characters): a spec sent to it names one as its `character.model` "
                       "and the job holds the definition. Schema: docs/characters.md.")
    csub = c.add_subparsers(dest="characters_command", required=True)
    cl = csub.add_parser("list", help="the stored characters and the shipped ones' names")
    cl.add_argument("--limit", type=int, default=50, help="at most this many (1..200)")
    ca = csub.add_parser("add", help="keep a character file under a name")
    ca.add_argument("file", metavar="FILE", help="a character definition (YAML or JSON)")
    ca.add_argument("--name", required=True,
                    help="lower-case letters, digits and _ (no shipped character's name)")
    cs = csub.add_parser("show", help="one character (its definition with --json)")
    cs.add_argument("name", metavar="NAME")
    for p in (cl, ca, cs):
        _url_arg(p)
        p.add_argument("--json", action="store_true")
        p.set_defaults(func=cmd_characters)
