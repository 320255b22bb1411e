"""The colour-shirt tracker's compiled kernels, loaded when a tracker is made rather than on its first frame.

numba compiles a kernel on its first call (with ``cache=True``, loads it from the on-disk cache): about 5 ms a
kernel, plus numba's own start-up once a process (its typing and target registries, about 150 ms). All 28 of
them fell on a take's first frame, which took 480 ms against 190 ms for the lock-on's own work (issue 18: no
frame over 100 ms). :func:`load_kernels` does that work when :class:`~mocap.shirt.pipeline.ShirtTracker` is
made, through numba's ``Dispatcher.compile`` with the argument types the tracker calls each kernel with.

Written here because numba's own way to compile ahead, a signature in ``@njit``, compiles at import: every
importer of these modules (the marker pipeline's command line too) would pay it, and a kernel with an explicit
signature refuses other argument types. Kernels keep compiling lazily for any other types; a missing or stale
entry here only moves a kernel's load back to its first call, which ``tests/test_shirt_pipeline_run.py`` catches
(:func:`loaded_signatures` before and after a tracked take).

    Inputs: none. Outputs: the kernels below compiled in this process.
"""

from __future__ import annotations

from numba import types as nt
from numba.core.registry import CPUDispatcher

from mocap.shirt import (arm_search, classify, colour_model, edt, histogram_search, hypotheses, id_maps, ik, ik_kernels,
                         pose_database, shirt_model, zbuffer)

_MODULES = (arm_search, classify, colour_model, edt, histogram_search, hypotheses, id_maps, ik, ik_kernels, pose_database,
            shirt_model, zbuffer)


def _c(dtype, ndim: int) -> nt.Array:
    """A C-contiguous array type."""
    return nt.Array(dtype, ndim, "C")


def _a(dtype, ndim: int) -> nt.Array:
    """An array type of any layout (a strided view)."""
    return nt.Array(dtype, ndim, "A")


f8, f4, i8, b1 = nt.float64, nt.float32, nt.int64, nt.boolean

# (kernel, argument types) as the tracker calls them, full method and baseline (recorded from the dispatchers'
# ``signatures`` after a take of each); one entry per kernel
_SIGNATURES = (
    (arm_search._arm_costs, (_c(f8, 3), _c(f8, 2), _c(f8, 1), f8, f8, f8, f8, f8, f8, f8, _c(i8, 1), _c(f4, 3), f4, f4, f8)),
    (classify._gather_mask, (_c(b1, 2), _c(i8, 1), _c(i8, 1), _c(i8, 1), _c(i8, 1))),
    (classify._argmin_and_min, (_c(f4, 2),)),
    (classify._assign_nearest, (_c(i8, 1), _c(i8, 1), _c(f4, 2), _c(i8, 1), _c(i8, 2), f4, _c(nt.int16, 1))),
    (classify._patch_sums, (_c(nt.int16, 1), i8, i8)),
    (colour_model._lookup_u8, (_c(nt.uint8, 1), nt.Array(f4, 1, "C", readonly=True))),
    (colour_model._block_norms, (_c(f4, 2), _c(f4, 1), i8)),
    (edt._exact_distances, (_c(nt.uint8, 3), _c(f4, 3))),
    (edt.not_patch_cells, (_c(nt.int16, 2), _c(i8, 1), i8)),
    (histogram_search._half_covered, (_c(b1, 2), i8, i8, i8)),
    (histogram_search._cell_counts, (_c(nt.uint8, 3), _c(b1, 2), _c(nt.int16, 1), i8, i8, i8, i8)),
    (histogram_search._uniformity, (_c(f4, 3), _c(i8, 1), _c(i8, 1), i8, i8, i8, f4, f4)),
    (hypotheses._hits, (_c(nt.int16, 1), _c(i8, 1), _c(nt.int16, 1), _c(i8, 1))),
    (id_maps._stray_thin_bits_out, (_c(nt.int16, 2), _c(nt.int16, 2))),
    (ik._bilinear, (_c(f8, 2), f8, f8, f8, i8, i8, _c(f8, 2))),
    (ik_kernels.place_anchors, (_c(f8, 3), _c(i8, 1), _c(f8, 2))),
    (ik_kernels.project_anchors, (_c(f8, 2), _c(f8, 3), _c(f8, 2), _a(f8, 1), _a(f8, 1), _a(f8, 1), _a(f8, 2))),
    (ik_kernels.whitened_errors, (_c(f8, 2), _c(f8, 2), _c(b1, 1), _c(f8, 3))),
    (ik_kernels.huber_rows, (_c(f8, 2), f8, _c(f8, 1))),
    (ik_kernels.anchor_jacobians, (_c(f8, 3), _c(i8, 1), _c(f8, 2))),
    (ik_kernels.projection_jacobians, (_c(f8, 1), _c(f8, 1), _c(f8, 1), _a(f8, 1), _a(f8, 1))),
    (ik_kernels.silhouette_field, (_c(f4, 2), f8)),
    (pose_database._percentile_pair, (_c(i8, 1), f8)),
    (pose_database._encode, (_c(nt.int8, 3), i8, i8, i8)),
    (shirt_model._anchor_sums, (_c(nt.int32, 1), _c(nt.int16, 1), _c(i8, 1), _c(f8, 2), i8, i8)),
    (shirt_model._pinhole_to_view, (_c(f8, 2), f8, f8, f8, f8, f8, f8, f8, f8, f8, f8)),
    (shirt_model._pinhole_box, (_c(f8, 2), f8, f8, f8, f8, f8)),
    (shirt_model._layer_maps, (_c(nt.int32, 2), i8, _c(nt.int16, 1), _c(nt.int16, 1))),
    (zbuffer._rasterise, (_c(f8, 2), _c(f8, 1), _c(i8, 2), i8, i8, b1, _c(i8, 1), _c(nt.int32, 1), _c(f8, 1),
                          _c(nt.int32, 1))),
)


def load_kernels() -> None:
    """Compile (or load from numba's cache) every kernel the tracker calls, for the types it calls it with.

    Cheap once done in a process: ``compile`` returns the existing overload.
    """
    for kernel, args in _SIGNATURES:
        kernel.compile(args)


def loaded_signatures() -> set[tuple[str, str]]:
    """``{(kernel's qualified name, argument types)}`` of every overload compiled so far in this process, over the
    kernels of :mod:`mocap.shirt`."""
    out = set()
    for module in _MODULES:
        for name, value in vars(module).items():
            if isinstance(value, CPUDispatcher) and value.py_func.__module__ == module.__name__:
                out.update((f"{module.__name__}.{name}", str(sig)) for sig in value.signatures)
    return out
