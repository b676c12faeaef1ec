"""Deprecated path of the forward sensor models' numba kernels (private).

The beam model's kernels moved to :mod:`probmap.models._beam_kernels`, the likelihood field's to
:mod:`probmap.models._likelihood_field_kernels` and the exact ray cast ``cast_exact`` to
:mod:`probmap.grid._traverse`, the one grid traversal kernel. This private path works for one
release: each old name is forwarded, with a ``DeprecationWarning``, when it is looked up
(nothing is compiled or imported before that).
"""

from __future__ import annotations

from probmap._deprecation import moved

__getattr__ = moved(
    __name__,
    {
        **dict.fromkeys(
            [
                "beam_log_likelihood",
                "beam_mixture",
                "cast_fan",
                "cast_rays",
                "exact_ranges",
                "fill_entry",
                "heading_bin",
                "table_beam_model",
                "table_normalisers",
                "table_ranges",
            ],
            "probmap.models._beam_kernels",
        ),
        **dict.fromkeys(
            ["endpoints_in_robot_frame", "likelihood_field_per_beam", "likelihood_field_sum"],
            "probmap.models._likelihood_field_kernels",
        ),
        "axis_setup": "probmap.grid._traverse",
        "cast_exact": "probmap.grid._traverse",
    },
)
