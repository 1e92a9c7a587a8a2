"""python -m devtools.synth [OUTDIR]: regenerate every sample capture and
the expected findings of the PROFIdrive samples (OUTDIR/expected/*.json) and
the intended parameter sets of the audit samples (OUTDIR/sets/*.csv)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .build import build_all, build_expected, build_sets


def main(argv: list[str]) -> int:
    # argparse, not a bare argv[1]: `--help` once became a directory named "--help" holding every sample
    parser = argparse.ArgumentParser(prog="python -m devtools.synth", description=__doc__.split(":", 1)[1].strip())
    parser.add_argument("outdir", nargs="?", default="sample_pcaps", help="where to write (default: sample_pcaps)")
    outdir = Path(parser.parse_args(argv[1:]).outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    for name, data in build_all().items():
        (outdir / name).write_bytes(data)
        print(f"{name}: {len(data)} bytes")
    (outdir / "expected").mkdir(exist_ok=True)
    for name, text in build_expected().items():
        (outdir / "expected" / f"{name}.json").write_text(text)
        print(f"expected/{name}.json")
    (outdir / "sets").mkdir(exist_ok=True)
    for name, data in build_sets().items():
        (outdir / "sets" / name).write_bytes(data)
        print(f"sets/{name}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv))
