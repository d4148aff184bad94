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

Needs a C and a C++ compiler (gcc, g++) and the Python headers (Python.h) of the interpreter.
"""

from __future__ import annotations

import argparse
import importlib.util
import logging
import os
import pathlib
import shutil
import subprocess
import sys
import sysconfig
import textwrap

INTERFACES = pathlib.Path(__file__).resolve().parent / "resources" / "interfaces"
#: package -> message dependencies (their libraries are linked)
PACKAGES = {"tf2_msgs": ["geometry_msgs", "std_msgs", "builtin_interfaces"],
            "bond": ["std_msgs", "builtin_interfaces"]}  # bond/Status: the heartbeat of Nav2's lifecycle manager


class BuildError(RuntimeError):
    pass


def _run(cmd: list[str], cwd: pathlib.Path | None = None) -> None:
    res = subprocess.run(cmd, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    if res.returncode != 0:
        raise BuildError(f"command failed ({res.returncode}): {' '.join(cmd)}\n{res.stdout[-4000:]}")


def _generate(package: str, src: pathlib.Path, out: pathlib.Path) -> None:
    """rosidl code generation for every ``msg/*.idl`` of ``src`` into ``out/<generator>``."""
    os.environ.setdefault("AMENT_PREFIX_PATH", sys.prefix)
    if sys.prefix not in os.environ["AMENT_PREFIX_PATH"].split(os.pathsep):
        os.environ["AMENT_PREFIX_PATH"] = sys.prefix + os.pathsep + os.environ["AMENT_PREFIX_PATH"]
    logging.getLogger("rosidl_cli").setLevel(logging.ERROR)  # duplicate entry points (egg-info + dist-info)
    # the extension classes directly: rosidl_cli's entry-point lookup refuses the duplicate entry points
    # that the wheels register (egg-info and dist-info), and its .msg -> .idl step needs catkin_pkg
    from rosidl_generator_c.cli import GenerateC
    from rosidl_generator_py.cli import GeneratePython
    from rosidl_typesupport_c.cli import GenerateCTypesupport
    from rosidl_typesupport_fastrtps_c.cli import GenerateFastRTPSCTypesupport
    from rosidl_typesupport_introspection_c.cli import GenerateIntrospectionCTypesupport

    files = [f"{src}:{p.relative_to(src)}" for p in sorted((src / "msg").glob("*.idl"))]
    if not files:
        raise BuildError(f"no msg/*.idl under {src}")
    include = [pathlib.Path(sys.prefix) / "share"]
    for name, cls in [
        ("c", GenerateC),
        ("py", GeneratePython),
        ("typesupport_c", GenerateCTypesupport),
        ("typesupport_fastrtps_c", GenerateFastRTPSCTypesupport),
        ("typesupport_introspection_c", GenerateIntrospectionCTypesupport),
    ]:
        cls(name).generate(package, files, include, out / name)


def _compile(package: str, deps: list[str], gen: pathlib.Path, stage: pathlib.Path) -> list[pathlib.Path]:
    """Compile the generated sources into the libraries and Python extension modules of ``package``."""
    prefix = pathlib.Path(sys.prefix)
    inc_root = gen / "include"
    hdr = inc_root / package / "msg"
    for sub in ("c", "typesupport_fastrtps_c", "typesupport_introspection_c"):
        for f in (gen / sub / "msg").rglob("*.h"):
            dst = hdr / f.relative_to(gen / sub / "msg")
            dst.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(f, dst)
    import numpy

    incs = [str(inc_root), str(prefix / "include")]
    incs += sorted(str(p) for p in (prefix / "include").iterdir() if p.is_dir())
    incs += [sysconfig.get_paths()["include"], numpy.get_include()]
    if not (pathlib.Path(sysconfig.get_paths()["include"]) / "Python.h").is_file():
        raise BuildError(f"Python.h not found in {sysconfig.get_paths()['include']}: install the Python headers")
    iflags = [f"-I{p}" for p in incs]
    lib_dir = stage / "lib"
    mod_dir = stage / package
    lib_dir.mkdir(parents=True, exist_ok=True)
    mod_dir.mkdir(parents=True, exist_ok=True)
    common = ["-shared", "-fPIC", "-O2", f"-L{lib_dir}", f"-L{prefix / 'lib'}"]
    lib_rpath = ["-Wl,-rpath,$ORIGIN"]
    mod_rpath = ["-Wl,-rpath,$ORIGIN/../../.."]  # <prefix>/lib/pythonX.Y/site-packages/<pkg> -> <prefix>/lib

    def dep_libs(suffix: str) -> list[str]:
        return [f"-l{d}__{suffix}" for d in deps]

    def lib(name: str) -> str:
        return str(lib_dir / f"lib{package}__{name}.so")

    def build(cc: str, out: str, sources: list[pathlib.Path], libs: list[str], rpath: list[str], std: str) -> None:
        _run([cc, std, *common, *rpath, *iflags, "-o", out, *map(str, sources), *libs])

    c_src = sorted((gen / "c" / "msg" / "detail").glob("*.c"))
    build("gcc", lib("rosidl_generator_c"), c_src,
          [*dep_libs("rosidl_generator_c"), "-lrosidl_runtime_c", "-lrcutils"], lib_rpath, "-std=c11")
    build("gcc", lib("rosidl_typesupport_introspection_c"),
          sorted((gen / "typesupport_introspection_c" / "msg" / "detail").glob("*.c")),
          [f"-l{package}__rosidl_generator_c", *dep_libs("rosidl_typesupport_introspection_c"),
           "-lrosidl_typesupport_introspection_c", "-lrosidl_runtime_c", "-lrcutils"], lib_rpath, "-std=c11")
    build("g++", lib("rosidl_typesupport_fastrtps_c"),
          sorted((gen / "typesupport_fastrtps_c" / "msg" / "detail").glob("*.cpp")),
          [f"-l{package}__rosidl_generator_c", *dep_libs("rosidl_typesupport_fastrtps_c"),
           *dep_libs("rosidl_typesupport_fastrtps_cpp"), *dep_libs("rosidl_generator_c"),
           "-lrosidl_typesupport_fastrtps_c", "-lrosidl_typesupport_fastrtps_cpp", "-lfastcdr", "-lrmw",
           "-lrosidl_runtime_c", "-lrcutils"], lib_rpath, "-std=c++17")
    build("g++", lib("rosidl_typesupport_c"), sorted((gen / "typesupport_c" / "msg").glob("*.cpp")),
          [f"-l{package}__rosidl_generator_c", "-lrosidl_typesupport_c", "-lrosidl_runtime_c", "-lrcpputils",
           "-lrcutils"], lib_rpath, "-std=c++17")
    build("gcc", lib("rosidl_generator_py"), sorted((gen / "py" / "msg").glob("*_s.c")),
          [f"-l{package}__rosidl_generator_c", f"-l{package}__rosidl_typesupport_c",
           *dep_libs("rosidl_generator_py"), *dep_libs("rosidl_generator_c"), *dep_libs("rosidl_typesupport_c"),
           "-lrosidl_runtime_c", "-lrcutils"], lib_rpath, "-std=c11")
    for ts in ("rosidl_typesupport_c", "rosidl_typesupport_fastrtps_c", "rosidl_typesupport_introspection_c"):
        build("gcc", str(mod_dir / f"{package}_s__{ts}.so"), [gen / "py" / f"_{package}_s.ep.{ts}.c"],
              [f"-l{package}__rosidl_generator_py", f"-l{package}__{ts}", f"-l{package}__rosidl_generator_c",
               "-lrmw", "-lrosidl_runtime_c", "-lrcutils"], mod_rpath + lib_rpath, "-std=c11")
    return sorted(lib_dir.glob("*.so"))


def _stage_package(package: str, src: pathlib.Path, gen: pathlib.Path, stage: pathlib.Path) -> None:
    """A pip-installable project in ``stage``: the Python package, its libraries and definitions."""
    mod_dir = stage / package
    (mod_dir / "__init__.py").write_text("")
    shutil.copytree(gen / "py" / "msg", mod_dir / "msg", dirs_exist_ok=True,
                    ignore=shutil.ignore_patterns("*.c", "*.h"))
    share = stage / "share" / package
    (share / "msg").mkdir(parents=True, exist_ok=True)
    for f in [*(src / "msg").glob("*.idl"), *(src / "msg").glob("*.msg"), *(gen / "c" / "msg").glob("*.json")]:
        shutil.copy2(f, share / "msg" / f.name)
    shutil.copy2(src / "package.xml", share / "package.xml")
    index = stage / "share" / "ament_index" / "resource_index" / "packages"
    index.mkdir(parents=True, exist_ok=True)
    (index / package).write_text("")
    version = "0.0.0"
    text = (src / "package.xml").read_text()
    if "<version>" in text:
        version = text.split("<version>", 1)[1].split("</version>", 1)[0].strip()
    (stage / "setup.py").write_text(textwrap.dedent(f"""\
        from glob import glob
        from setuptools import setup

        setup(
            name="ros-{package.replace('_', '-')}",
            version="{version}",
            description="{package} built from its definition by deepbbs_ros (deepbbs-ros build-interfaces)",
            packages=["{package}", "{package}.msg"],
            package_data={{"{package}": ["*.so"]}},
            data_files=[
                ("lib", glob("lib/*.so")),
                ("share/{package}", ["share/{package}/package.xml"]),
                ("share/{package}/msg", glob("share/{package}/msg/*")),
                ("share/ament_index/resource_index/packages", ["share/ament_index/resource_index/packages/{package}"]),
            ],
            zip_safe=False,
        )
        """))


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
