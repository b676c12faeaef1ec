"""Deprecated path of the beam model's EM fit, now in :mod:`probmap.models.beam`.

The fit on arrays (:func:`~probmap.models.beam.fit_beam_model`, Probabilistic Robotics
Table 6.2) moved beside the beam model it fits; reading a log (``fit_log``) moved to
:mod:`probmap.pipelines.fit`. This path works for one release: each old name is forwarded, with a
``DeprecationWarning``, when it is looked up.
"""

from __future__ import annotations

from probmap._deprecation import moved

__getattr__ = moved(
    __name__,
    {
        **dict.fromkeys(
            ["FitResult", "component_densities", "fit_beam_model"], "probmap.models.beam"
        ),
        "fit_log": "probmap.pipelines.fit",
    },
)
