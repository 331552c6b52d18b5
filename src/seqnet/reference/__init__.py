"""The reference side of every pipeline: one :class:`Reference` protocol, two implementations.

* :class:`~seqnet.reference.traverse.TraverseReference`: a dataset's reference traverse, described on
  the fly (in memory or memory-mapped), searched exactly;
* :class:`seqnet.maps.Map`: a prepared map on disk, searched through its ANN index.

Evaluation (:func:`seqnet.eval.runner.run`), HVPR (:func:`seqnet.methods.rank.rank`) and the
localiser (:class:`seqnet.localize.localizer.Localizer`) are written once against it.
"""

from ..methods.protocol import Reference
from .traverse import TraverseReference

__all__ = ["Reference", "TraverseReference"]
