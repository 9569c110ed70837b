"""Compile the law's modules with mypyc, in place (controller/compiled_law.py says which and why).

    .venv/bin/python -m controller.tools.compile_law          # make setup and make compile run it
    .venv/bin/python -m controller.tools.compile_law --clean  # remove the extensions: the sources run

The extensions land beside their sources (``controller/core/control_law.cpython-311-*.so``), the
group's shared library as ``controller/compiled_law__mypyc.*.so``, the build's C files under
``build/mypyc``; ``controller/compiled_law.json`` records the SHA-256 of each source compiled, last,
so that an interrupted build is never taken for a finished one. Needs mypy (the dev extra) and a
C compiler. About 2 minutes from an empty ``build/`` on the 2-core machines, 40 s when only a few
sources changed.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from controller.compiled_law import (
    COMPILED_MODULES,
    GROUP,
    ROOT,
    extension_path,
    manifest_path,
    source_path,
    write_manifest,
)


def clean(root: Path = ROOT) -> list[Path]:
    """Remove the extensions and the manifest; what was removed."""
    removed = []
    for module in (*COMPILED_MODULES, f"{GROUP}__mypyc"):
        while (ext := extension_path(module, root)) is not None:
            ext.unlink()
            removed.append(ext)
    manifest = manifest_path(root)
    if manifest.exists():
        manifest.unlink()
        removed.append(manifest)
    return removed


def compile_law(root: Path = ROOT, verbose: bool = False) -> Path:
    """mypyc over the modules, then the manifest; raises SystemExit with the build's error."""
    from mypyc.build import mypycify  # the dev extra's mypy: imported only to compile
    from setuptools import setup  # type: ignore[import-untyped]  # no stubs; only its setup() is called

    clean(root)
    paths = [str(source_path(m, root).relative_to(root)) for m in COMPILED_MODULES]
    cwd = os.getcwd()
    os.chdir(root)  # mypy reads [tool.mypy] from the pyproject.toml here; the paths are relative to it
    try:
        build_dir = Path("build") / "mypyc"
        # multi_file: a C file per module instead of one for the whole group, which gcc -O3 takes
        # much longer over: the whole compilation from an empty build/ took 118 s against 169 s
        # (medians of 2, alternating, this 2-core host), with the same instructions per contour
        # cycle (929 128 against 929 190, `python -m controller.tools.bench.cycle_work --task
        # contour --skip 3200 --cycles 200 --instructions`)
        extensions = mypycify(
            paths, group_name=GROUP, target_dir=str(build_dir), opt_level="3", multi_file=True
        )
        setup(
            name="cheope-compiled-law",
            ext_modules=extensions,
            script_args=[
                *([] if verbose else ["--quiet"]),
                "build_ext",
                # the group's header lands in the folder of its package (GROUP is controller.*), the
                # modules' C files that include it at the top of build_dir
                "--include-dirs",
                str(build_dir / "controller"),
                "--inplace",
                "--build-temp",
                str(build_dir / "temp"),
                "--build-lib",
                str(build_dir / "lib"),
            ],
        )
    finally:
        os.chdir(cwd)
    return write_manifest(root=root)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="compile_law", description=__doc__.split("\n\n")[0])
    ap.add_argument("--clean", action="store_true", help="remove the compiled extensions instead")
    ap.add_argument("-v", "--verbose", action="store_true", help="the compiler's commands")
    args = ap.parse_args(argv)
    if args.clean:
        removed = clean()
        print(f"compile_law: removed {len(removed)} file(s); the law runs from its sources")
        return 0
    manifest = compile_law(verbose=args.verbose)
    print(
        f"compile_law: {len(COMPILED_MODULES)} modules compiled; sources recorded in {manifest.relative_to(ROOT)}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
