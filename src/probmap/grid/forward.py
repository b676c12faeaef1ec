"""Deprecated path of the forward sensor models, now in :mod:`probmap.models`.

The beam model (:class:`~probmap.models.beam.BeamModel`) moved to :mod:`probmap.models.beam`
beside its parameters and EM fit, the likelihood field to
:mod:`probmap.models.likelihood_field`, and what both work on (:class:`GridGeometry`,
:func:`occupied_mask`) to :mod:`probmap.models.grid_map`. This path works for one release: each
old name is forwarded, with a ``DeprecationWarning``, when it is looked up.
"""

from __future__ import annotations

from probmap._deprecation import moved

__getattr__ = moved(
    __name__,
    {
        "BeamModel": "probmap.models.beam",
        "LikelihoodField": "probmap.models.likelihood_field",
        "GridGeometry": "probmap.models.grid_map",
        "occupied_mask": "probmap.models.grid_map",
    },
)
