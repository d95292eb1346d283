"""Where each operation is explained and what it computes in the thesis: its user-guide page
(``docs/guide/<page>.rst``), the thesis equation or section and the library function. Read by
the README's operation table (``otgeo routes --update README.md``) and the OpenAPI document
(``x-guide``, ``x-thesis``, ``x-function`` on each operation; the viewer links to the page);
tests/service/test_route_list.py checks that every operation has an entry."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class OperationDoc:
    page: str  # docs/guide/<page>.rst
    thesis: str  # equation, algorithm, section or figure of the thesis
    function: str  # the library function that computes it


OPERATION_DOCS = {
    "distances": OperationDoc("convolutional", "eq. 3.10, Alg. 1; W1 eq. 2.1",
                              "solvers.convolutional.wasserstein_distance"),
    "distance-matrices": OperationDoc("convolutional", "eq. 3.10, Alg. 1; W1 eq. 2.1 (pairwise)",
                                      "solvers.convolutional.distance_matrix"),
    "barycenters": OperationDoc("convolutional", "eq. 3.13, Alg. 2-3",
                                "solvers.convolutional.barycenter"),
    "barycenter-batches": OperationDoc("convolutional", "eq. 3.13, Alg. 2-3 (per weight "
                                       "vector; Fig. 3.4)",
                                       "solvers.convolutional.barycenters"),
    "interpolations": OperationDoc("convolutional", "eq. 3.16, Alg. 2",
                                   "solvers.convolutional.displacement_interpolation"),
    "propagations": OperationDoc("convolutional", "eq. 3.17, Alg. 4",
                                 "solvers.convolutional.wasserstein_propagation"),
    "pointwise-distances": OperationDoc("emd", "§2.5 (d_W^k)", "solvers.emd.pointwise_distances"),
    "flows": OperationDoc("emd", "eq. 2.1-2.5", "solvers.emd.earth_movers_distance"),
    "volumetric-distances": OperationDoc("emd", "§2.6",
                                         "solvers.emd.volumetric.volumetric_distances"),
    "volumetric-paths": OperationDoc("emd", "§2.6", "solvers.emd.volumetric.volumetric_path"),
    "feature-distances": OperationDoc("emd", "§2.7, Fig. 2.14", "solvers.emd.distance_to_features"),
    "anisotropic-distances": OperationDoc("emd", "§2.7, Fig. 2.15",
                                          "solvers.emd.anisotropy.anisotropic_w1"),
    "w1-barycenters": OperationDoc("emd", "eq. 2.7", "solvers.emd.w1_barycenter"),
    "path-plans": OperationDoc("emd", "eq. 2.6, Fig. 2.12",
                               "solvers.emd.path_planning.w1_path_planning"),
    "soft-maps": OperationDoc("softmaps", "eq. 3.18, ch. 4", "solvers.softmaps.soft_map"),
    "soft-map-analyses": OperationDoc("softmaps", "eq. 4.2-4.6, §4.6",
                                      "solvers.softmaps.point_maps"),
    "histogram-propagations": OperationDoc("histograms", "ch. 5, Prop. 13",
                                           "solvers.histograms.propagate_histograms"),
    "metric-histogram-propagations": OperationDoc("histograms", "§5.4",
                                                  "solvers.histograms.propagate_circular"),
    "color-transfers": OperationDoc("applications", "§3.7, Fig. 3.12",
                                    "solvers.color.color_transfer"),
    "brdf-interpolations": OperationDoc("applications", "§3.7, Fig. 3.11",
                                        "solvers.convolutional.brdf.interpolate_brdfs"),
    "skeleton-layouts": OperationDoc("applications", "§3.7, Fig. 3.13",
                                     "solvers.convolutional.skeleton.skeleton_layout"),
    "shape-interpolations": OperationDoc("applications", "§3.7",
                                         "solvers.convolutional.shapes.shape_interpolations"),
}


def openapi_extra(name: str) -> dict | None:
    """The operation's ``x-`` fields: its guide page as served under ``/guide/``, its thesis
    reference and library function."""
    doc = OPERATION_DOCS.get(name)
    if doc is None:
        return None
    return {"x-guide": f"/guide/guide/{doc.page}.html", "x-thesis": doc.thesis,
            "x-function": doc.function}
