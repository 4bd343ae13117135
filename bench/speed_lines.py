"""Lines of the package that exist only for speed: what would fly the same without them.

    python bench/speed_lines.py                # this tree
    python bench/speed_lines.py --tree DIR     # another checkout (its own layout)

A module counts when removing it leaves every flight the same to the bit and only slower:
a second form of something the package also has in a plain form (a compiled or generated
tick, a hand-written fast path), or the machinery that builds such forms. Lines written out
for speed inside other modules are not counted (the figure is a floor). Counted are all
lines of ``*.py`` and ``*.c`` files under the package folders, tests and bench excluded.
"""

from __future__ import annotations

import argparse
from pathlib import Path

# file stem (unique across the package in every layout this knows) → why it is speed only
SPEED_ONLY = {
    "fused": ("the TFL tick generated as one function per flight (tfl_controller.py flies "
              "without it)"),
    "fused_native": "the fused tick's arithmetic laid out for the C compiler",
    "compiled": "the compiled path tracker (the reference jets give the same numbers)",
    "projection": "the compiled tracker's projection step (the reference jets: the same)",
    "jetcode": "jets traced into straight-line code",
    "kernelgen": "tapes compiled into Python functions",
    "detector_native": "glue calling the detector's compiled tick",
    "physics_native": "the RK4 step handed to the C compiler",
    "native": "building and caching compiled cores",
    "ctranslate": "Python float functions translated to C",
    "cruntime": "the C the translated functions call",
    "frontend": "the seam's front end: a pure function lowered for translation",
    "lowering": "the front end's inlining, unrolling and scalar replacement",
    "values": "the front end's values: tuples as one float each",
    "mcapfast": "a lean MCAP message path inside the library's writer",
    "frames_c": "the recorder's frame hot path in C (and its .c file)",
    "jsonenc": "JSON printed like repr, fast",
    "jsonobj": "a whole JSON object in one msgspec call",
    "recordplan": "precompiled tick records",
    "lite": "light MAVLink message classes instead of pymavlink's",
    "recovery_native": "the safe law's tick mirrored by hand in C",
    "frames_native": "the frame conversion's FMA order replayed in C",
}
ROOTS = ("tfl_mav", "sitl", "tools", "harness")


def count(tree: Path) -> tuple[int, dict[str, int]]:
    total, speed = 0, {}
    for root in ROOTS:
        for f in sorted((tree / root).rglob("*")):
            if f.suffix not in (".py", ".c") or "__pycache__" in f.parts:
                continue
            n = len(f.read_text(errors="replace").splitlines())
            total += n
            if f.stem in SPEED_ONLY:
                speed[str(f.relative_to(tree))] = n
    return total, speed


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tree", type=Path, default=Path(__file__).resolve().parents[1],
                    help="checkout to count (default: this one)")
    args = ap.parse_args(argv)
    total, speed = count(args.tree)
    for path, n in sorted(speed.items(), key=lambda kv: -kv[1]):
        print(f"{n:6d}  {path:48s} {SPEED_ONLY[Path(path).stem]}")
    s = sum(speed.values())
    print(f"{s:6d}  of {total} package lines exist only for speed ({100.0 * s / total:.1f} %)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
