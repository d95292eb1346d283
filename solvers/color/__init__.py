"""Color transfer over chrominance histograms (thesis §3.7, Fig. 3.12).

=====================  ==================================================================
module                 what it computes
=====================  ==================================================================
``transfer``           :func:`color_transfer`: the whole method, one result object
``chrominance``        ab histograms on a grid over [-128, 128]^2, their barycenters
                       (eq. 3.13, Alg. 2, Alg. 3), plans' barycentric projections T_i
``luminance``          1-D OT of L* in closed form (quantile matching)
``lab``                sRGB <-> CIE-Lab: scikit-image reference and the fused fast path
``images``             image files in/out (Pillow, EXIF orientation, 8/16 bits, alpha)
``picture``            a histogram as a picture (Fig. 3.12, bottom row)
=====================  ==================================================================
"""

from solvers.color.chrominance import ab_histogram, chrominance_barycenters
from solvers.color.images import probe_image, read_image, write_image
from solvers.color.lab import lab_to_rgb, rgb_to_lab
from solvers.color.luminance import luminance_maps
from solvers.color.picture import histogram_picture
from solvers.color.transfer import ColorTransferResult, color_transfer

__all__ = [
    "ColorTransferResult",
    "ab_histogram",
    "chrominance_barycenters",
    "color_transfer",
    "histogram_picture",
    "lab_to_rgb",
    "luminance_maps",
    "probe_image",
    "read_image",
    "rgb_to_lab",
    "write_image",
]
