"""Builds jaxenvs' native engine (jaxenvs/physics/native/engine.cc) during `pip install`.

The metadata lives in pyproject.toml; this file only adds the one C++ extension: an XLA
FFI handler that steps MuJoCo's C engine (see jaxenvs/physics/native/__init__.py). It is compiled
against the headers of the jaxlib and mujoco in the build environment (pyproject's
build-system requires) and linked to that mujoco's libmujoco. The extension is optional:
where it cannot be built (no C++ compiler), the install goes on and jaxenvs steps the C
engine through a Python callback instead, saying so when that engine is first used.
"""

from __future__ import annotations

import glob
import os

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext


class BuildNative(build_ext):
    """build_ext that finds jaxlib's and mujoco's headers and records their versions."""

    def build_extension(self, ext: Extension) -> None:
        import jaxlib
        import mujoco

        jaxlib_include = os.path.join(os.path.dirname(jaxlib.__file__), "include")
        mujoco_dir = os.path.dirname(mujoco.__file__)
        libs = sorted(glob.glob(os.path.join(mujoco_dir, "libmujoco.so*")))
        if not libs:
            raise RuntimeError(f"no libmujoco shared library in {mujoco_dir}")
        ext.include_dirs = [os.path.join(mujoco_dir, "include")]
        # the versions it is built against, read back by jaxenvs.physics.native before first use
        ext.define_macros = [
            ("JAXENVS_BUILT_JAXLIB", f'"{jaxlib.__version__}"'),
            ("JAXENVS_BUILT_MUJOCO", f'"{mujoco.__version__}"'),
        ]
        # jaxlib's FFI headers as system headers: their warnings are not ours
        ext.extra_compile_args = [
            "-std=c++17",
            "-O2",
            "-fvisibility=hidden",
            "-fvisibility-inlines-hidden",
            "-isystem",
            jaxlib_include,
        ]
        ext.extra_link_args = [
            f"-L{mujoco_dir}",
            f"-l:{os.path.basename(libs[-1])}",
            # an installed (non-editable) jaxenvs sits beside mujoco in site-packages
            "-Wl,-rpath,$ORIGIN/../../../mujoco",
        ]
        super().build_extension(ext)


setup(
    ext_modules=[
        Extension(
            "jaxenvs.physics.native._engine",
            sources=["jaxenvs/physics/native/engine.cc", "jaxenvs/physics/native/hfield.cc"],
            language="c++",
            optional=True,
        )
    ],
    cmdclass={"build_ext": BuildNative},
)
