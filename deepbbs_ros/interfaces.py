"""Build and install ROS 2 message packages that PyPI has no wheel for (``tf2_msgs``, ``bond``).

The definitions ship with this package (``deepbbs_ros/resources/interfaces/<package>/msg/*.idl``, the
``*.msg`` beside them for reference, ``package.xml``). The code is generated with the rosidl generators that
the ROS 2 Jazzy PyPI wheels install (rosidl_generator_c / _py, rosidl_typesupport_c / _fastrtps_c /
_introspection_c), compiled with gcc / g++ against the wheels' headers and libraries, and installed into the
running environment as a small local wheel (``pip install``): the Python package into site-packages, the
libraries into ``<prefix>/lib`` (where the ROS wheels keep theirs and look them up), the definitions into
``<prefix>/share/<package>``. ``make venv`` runs it; after a plain ``pip install`` run it once::

    deepbbs-ros build-interfaces            # build and install what is missing
    deepbbs-ros build-interfaces --force    # rebuild
    python -m deepbbs_ros.interfaces        # the same

Needs a C and a C++ compiler (gcc, g++) and the Python headers (Python.h) of the interpreter. The generate, compile
and stage steps: deepbbs_ros/interfaces_build.py (imported from here too).
"""

from __future__ import annotations

import argparse
import importlib.util
import pathlib
import shutil
import subprocess
import sys

from deepbbs_ros.interfaces_build import (  # noqa: F401  (re-exported)
    BuildError,
    _compile,
    _generate,
    _run,
    _stage_package,
)

INTERFACES = pathlib.Path(__file__).resolve().parent / "resources" / "interfaces"
#: package -> message dependencies (their libraries are linked)
PACKAGES = {"tf2_msgs": ["geometry_msgs", "std_msgs", "builtin_interfaces"],
            "bond": ["std_msgs", "builtin_interfaces"]}  # bond/Status: the heartbeat of Nav2's lifecycle manager


def _setuptools_version() -> tuple[int, ...]:
    try:
        import setuptools
    except ImportError:
        return (0,)
    return tuple(int(x) for x in setuptools.__version__.split(".")[:2] if x.isdigit())


def installed(package: str) -> bool:
    """True when ``<package>.msg`` imports with its C type support in this environment."""
    if importlib.util.find_spec(package) is None:
        return False
    code = (f"import {package}.msg as m, rosidl_generator_py.import_type_support_impl as i; "
            f"i.import_type_support({package!r})")
    return subprocess.run([sys.executable, "-c", code], capture_output=True).returncode == 0


def build_package(package: str, build_dir: pathlib.Path, install: bool = True) -> pathlib.Path:
    src = INTERFACES / package
    if not (src / "package.xml").is_file():
        raise BuildError(f"no definition of {package} under {INTERFACES}")
    for tool in ("gcc", "g++"):
        if shutil.which(tool) is None:
            raise BuildError(f"{tool} not found: install a C/C++ compiler (e.g. apt-get install build-essential)")
    work = build_dir / package
    shutil.rmtree(work, ignore_errors=True)
    gen, stage = work / "gen", work / "stage"
    _generate(package, src, gen)
    _compile(package, PACKAGES[package], gen, stage)
    _stage_package(package, src, gen, stage)
    if install:
        # the environment's setuptools builds the local wheel (no download) when it can: setuptools >= 70.1 has
        # bdist_wheel itself, older ones need the wheel package; else pip fetches a build backend
        own = importlib.util.find_spec("wheel") is not None or _setuptools_version() >= (70, 1)
        _run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--force-reinstall",
              *(["--no-build-isolation"] if own else []), str(stage)])
    return stage


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("packages", nargs="*", default=sorted(PACKAGES), help=f"default: {' '.join(sorted(PACKAGES))}")
    p.add_argument("--build-dir", type=pathlib.Path, default=None,
                   help="where to generate and compile (default: a temporary folder)")
    p.add_argument("--force", action="store_true", help="rebuild even when the package imports already")
    p.add_argument("--no-install", action="store_true", help="build and stage only")
    args = p.parse_args(argv)
    if args.build_dir is None:
        import tempfile

        with tempfile.TemporaryDirectory(prefix="deepbbs-interfaces-") as tmp:
            args.build_dir = pathlib.Path(tmp)
            return _build_all(args)
    return _build_all(args)


def _build_all(args: argparse.Namespace) -> int:
    for package in args.packages:
        if package not in PACKAGES:
            print(f"build-interfaces: unknown package {package!r} (known: {', '.join(PACKAGES)})", file=sys.stderr)
            return 1
        if not args.force and not args.no_install and installed(package):
            print(f"build-interfaces: {package} already installed")
            continue
        try:
            stage = build_package(package, args.build_dir, install=not args.no_install)
        except BuildError as err:
            print(f"build-interfaces: {package}: {err}", file=sys.stderr)
            return 1
        where = "" if args.build_dir.name.startswith("deepbbs-interfaces-") else f" in {stage}"
        print(f"build-interfaces: {package} built{where}" + ("" if args.no_install else " and installed"))
        if not args.no_install and not installed(package):
            print(f"build-interfaces: {package} installed but does not import", file=sys.stderr)
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
