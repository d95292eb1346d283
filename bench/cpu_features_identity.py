"""Whether results depend on the CPU's vector extensions: prints a W1 barycenter (spot, 3
Dirac inputs), a convolutional W2 distance (spot, two bumps, gamma 0.01) and a hash of a
colour transfer's output, for runs of this script under different environments, e.g. native
against AVX2-limited numpy / MKL / OpenBLAS / numba on an AVX-512 machine::

    cpu run env .venv/bin/python bench/cpu_features_identity.py
    cpu run env NPY_DISABLE_CPU_FEATURES="X86_V4 AVX512_ICL AVX512_SPR" \\
        MKL_ENABLE_INSTRUCTIONS=AVX2 OPENBLAS_CORETYPE=Haswell NUMBA_CPU_NAME=haswell \\
        NUMBA_CACHE_DIR=/tmp/nb_haswell .venv/bin/python bench/cpu_features_identity.py

(numpy 2.4 names its AVX-512 dispatch group ``X86_V4``: ``np.show_runtime()`` lists it
under ``not_found`` when it is disabled.)
"""

import hashlib
import os
import sys
from pathlib import Path

for var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(var, "1")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402
from skimage import data  # noqa: E402

from solvers.color import color_transfer  # noqa: E402
from solvers.convolutional import wasserstein_distance  # noqa: E402
from solvers.domains import load_mesh  # noqa: E402
from solvers.emd import exact  # noqa: E402

mesh = load_mesh(ROOT.parent / "shared" / "meshes" / "spot.obj")
k = 3
diracs = np.zeros((mesh.n, k))
diracs[[i * mesh.n // k for i in range(k)], np.arange(k)] = 1.0
bary = exact.w1_barycenter(mesh, diracs)


def bump(vertex: int) -> np.ndarray:
    d = np.linalg.norm(mesh.vertices - mesh.vertices[vertex], axis=1)
    b = np.exp(-(d / 0.2) ** 2)
    return b / b.sum()


w2 = wasserstein_distance(mesh, bump(0), bump(1500), gamma=0.01)
out = color_transfer([data.astronaut(), data.coffee()], [0, 1], recolor=[0]).images[0][0]
print("w1 barycenter", repr(bary.value), bary.iterations, "| w2", repr(float(w2.value)),
      w2.iterations, "| colour sha1", hashlib.sha1(out.tobytes()).hexdigest()[:12])
