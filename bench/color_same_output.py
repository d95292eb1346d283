"""Whether two source trees give the same default colour transfer, bit for bit: 10 ordered
pairs of scikit-image photographs and this folder's 12 Mpx pair (bench/color.py's
``upscale`` of astronaut -> coffee), ``np.array_equal`` per output.

Usage: ``cpu run env PYTHONPATH=$PWD .venv/bin/python bench/color_same_output.py ROOT_A
ROOT_B`` (each tree imported in its own process; e.g. main's tree from ``git archive``).
"""

import subprocess
import sys
import tempfile

import numpy as np

NAMES = ["astronaut", "coffee", "chelsea", "rocket", "immunohistochemistry",
         "hubble_deep_field"]
PAIRS = [(0, 1), (1, 0), (2, 3), (3, 2), (4, 5), (5, 1), (1, 2), (2, 4), (3, 5), (0, 4)]


def outputs(root: str, path: str) -> None:
    sys.path[:0] = [root, root + "/bench"]
    from color import upscale
    from skimage import data

    from solvers.color import color_transfer

    imgs = [getattr(data, n)() for n in NAMES]
    res = {f"{NAMES[i]}->{NAMES[j]}": color_transfer([imgs[i], imgs[j]], [0, 1],
                                                     recolor=[0]).images[0][0]
           for i, j in PAIRS}
    res["12mp"] = color_transfer([upscale(imgs[0]), upscale(imgs[1])], [0, 1],
                                 recolor=[0]).images[0][0]
    np.savez(path, **res)


def main(a: str, b: str) -> int:
    with tempfile.TemporaryDirectory() as tmp:
        files = [f"{tmp}/{k}.npz" for k in "ab"]
        for root, path in zip((a, b), files, strict=True):
            subprocess.run([sys.executable, __file__, "--save", root, path], check=True)
        ra, rb = (np.load(f) for f in files)
        same = True
        for k in ra.files:
            eq = np.array_equal(ra[k], rb[k])
            same &= eq
            print(f"{k:40s} {ra[k].shape} {'identical' if eq else 'DIFFERENT'}")
    print("all identical" if same else "outputs differ")
    return 0 if same else 1


if __name__ == "__main__":
    if sys.argv[1] == "--save":
        outputs(sys.argv[2], sys.argv[3])
    else:
        sys.exit(main(sys.argv[1], sys.argv[2]))
