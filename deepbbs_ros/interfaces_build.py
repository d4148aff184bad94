"""The steps that make one ROS 2 message package's local wheel (deepbbs_ros/interfaces.py runs them): the code
generated with the rosidl generators (:func:`_generate`), compiled with gcc / g++ against the ROS wheels' headers and
libraries (:func:`_compile`), and staged as a Python package with its libraries and definitions
(:func:`_stage_package`); a failed step is a :class:`BuildError`."""

from __future__ import annotations

import logging
import os
import pathlib
import shutil
import subprocess
import sys
import sysconfig
import textwrap


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
