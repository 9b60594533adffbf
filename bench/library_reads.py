"""The library's reads in process, without HTTP: CPU per query of the answer and the find.

    .venv/bin/python bench/library_reads.py [--families 200] [--per-family 50] [--queries 300]
        [--db PATH]

Fills a SQLite library as `bench/library_scale.py` does (10,000 domino CMRTs in 200 families;
`--db` keeps the file and reuses it on the next run), then asks the same random queries twice
through a fresh repository: `application.answers.serve` (the plain answer of
`GET /cmrts/interpolate`), `Repository.find_cmrts` and `Repository.find_cmrt_keys` (what
`GET /cmrts?...&tolerance=5` reads), and prints each pass's CPU ms per query: the first pass
reads what the store has not kept yet, the second what it has. Run it with another checkout's
interpreter and `PYTHONPATH` for a before / after (a method the other lacks is skipped).
"""

from __future__ import annotations

import argparse
import random
import tempfile
import time
from pathlib import Path

from application import answers
from bench.library_scale import MASS_HI, MASS_LO, TOLERANCE, _entries, _fill
from store import open_repository


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--families", type=int, default=200)
    ap.add_argument("--per-family", type=int, default=50)
    ap.add_argument("--queries", type=int, default=300)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--db", type=Path, default=None)
    args = ap.parse_args()
    db = args.db or Path(tempfile.mkdtemp(prefix="cmrt-libreads-")) / "cmrt.db"
    url = f"sqlite:///{db}"
    if not db.exists():
        _fill(url, _entries(args.families, args.per_family, args.seed))
    repo = open_repository(url)
    rng = random.Random(args.seed)
    qs = [(f"domino_{rng.randrange(args.families):03d}", round(rng.uniform(MASS_LO, MASS_HI), 2))
          for _ in range(args.queries)]
    kinds = {
        "answer": lambda f, m: answers.serve(repo, answers.LibraryQuery(f, {"mass": m})),
        "find": lambda f, m: repo.find_cmrts(f, {"mass": m}, tolerance=TOLERANCE),
    }
    if hasattr(repo, "find_cmrt_keys"):
        kinds["find keys"] = lambda f, m: repo.find_cmrt_keys(f, {"mass": m}, tolerance=TOLERANCE)
    print(f"{args.families * args.per_family} CMRTs in {args.families} families, "
          f"{args.queries} queries")
    print("| read | first pass CPU ms / query | second pass CPU ms / query |")
    print("|---|---|---|")
    for name, fn in kinds.items():
        passes = []
        for _ in range(2):
            c0 = time.process_time()
            for f, m in qs:
                fn(f, m)
            passes.append((time.process_time() - c0) / len(qs) * 1000)
        print(f"| {name} | {passes[0]:.2f} | {passes[1]:.2f} |")
    with open("/proc/loadavg") as f:
        print("load average", " ".join(f.read().split()[:3]))


if __name__ == "__main__":
    main()
