"""Compile numba's cached kernels into NUMBA_CACHE_DIR while the image is built, so that a
new container's first job loads them instead of compiling: every operation's warm-up
(:mod:`service.warm`; the color transfer's runs a job's code on two tiny PNGs)."""

import os

from service.operations import build_registry
from service.warm import warm_all


def main() -> None:
    assert os.environ.get("NUMBA_CACHE_DIR"), "set NUMBA_CACHE_DIR"
    warm_all(build_registry())
    compiled = sum(len(files) for _, _, files in os.walk(os.environ["NUMBA_CACHE_DIR"]))
    print(f"numba cache: {compiled} files in {os.environ['NUMBA_CACHE_DIR']}")
    assert compiled > 0


if __name__ == "__main__":
    main()
