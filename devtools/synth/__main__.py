"""python -m devtools.synth [OUTDIR]: regenerate every sample capture and
the expected findings of the PROFIdrive samples (OUTDIR/expected/*.json) and
the intended parameter sets of the audit samples (OUTDIR/sets/*.csv)."""

from __future__ import annotations

import sys
from pathlib import Path

from .build import build_all, build_expected, build_sets


def main(argv: list[str]) -> int:
    outdir = Path(argv[1] if len(argv) > 1 else "sample_pcaps")
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
