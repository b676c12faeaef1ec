"""Deprecated path of the MAP mapper's numba kernels, now :mod:`probmap.mapping._map_kernels`.

The beam model's own kernels moved to :mod:`probmap.models._beam_kernels`. This private path
works for one release: each old name is forwarded, with a ``DeprecationWarning``, when it is
looked up (nothing is compiled or imported before that).
"""

from __future__ import annotations

from probmap._deprecation import moved

__getattr__ = moved(
    __name__,
    {
        **dict.fromkeys(
            [
                "all_gains",
                "apply_flip",
                "build_entries",
                "evaluate_beams",
                "flip_gain",
                "invert_entries",
                "sweep",
            ],
            "probmap.mapping._map_kernels",
        ),
        "beam_log_likelihood": "probmap.models._beam_kernels",
        "beam_log_likelihoods": "probmap.models._beam_kernels",
    },
)
