"""Build hook: compile vpsim's kernels into the package while ``pip install .`` builds it.

Everything else about the package is in pyproject.toml. The kernels are Numba functions cached on disk beside
their modules; compiling them here (``python -m vpsim.precompile`` on the built copy) means a user's first
run loads them in about a second instead of compiling them for up to a minute. The cache is stamped with
each kernel's sources and the processor it was built for, so a copy that does not fit is ignored and
compiled anew at first use. ``VPSIM_PRECOMPILE=0`` skips the step; an editable install skips it too (kernels
then compile on first use and are cached beside the sources). A failure here never fails the install.
"""

import os
import subprocess
import sys
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py


class BuildPyWithKernels(build_py):
    def run(self):
        super().run()
        if getattr(self, "editable_mode", False) or os.environ.get("VPSIM_PRECOMPILE", "1") == "0":
            return
        build_lib = Path(self.build_lib).resolve()
        if not (build_lib / "vpsim" / "precompile.py").exists():
            return
        env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}  # the cache goes in-tree
        env["PYTHONPATH"] = os.pathsep.join([str(build_lib), *filter(None, [env.get("PYTHONPATH")])])
        print(
            "vpsim: compiling the kernels into the package (about a minute on 2 cores; "
            "VPSIM_PRECOMPILE=0 skips it)",
            file=sys.stderr,
            flush=True,
        )
        rc = subprocess.call([sys.executable, "-m", "vpsim.precompile"], env=env)
        if rc != 0:
            print("vpsim: precompiling failed; kernels will compile on first use", file=sys.stderr)


setup(cmdclass={"build_py": BuildPyWithKernels})
