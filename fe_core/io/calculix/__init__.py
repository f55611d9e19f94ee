"""CalculiX / Abaqus input decks: reading and writing them (:mod:`.deck`), running ``ccx`` (:mod:`.runner`),
reading its output (:mod:`.results`) and the segment matrices of route A (:mod:`.segments`).
The model file's ``solver = "calculix"`` builder is :mod:`fe_core.io.model_toml.calculix_model`."""

from .deck import Card, Deck, DeckError, NumberRef, read_deck
from .results import ResultError, node_dof_weights, read_eigenfrequencies, read_steady_state, read_storage
from .runner import INSTALL_HINT, CcxError, CcxMissing, CcxTimeout, ccx_executable, run_ccx
from .segments import Segment, segment_matrices

__all__ = ["Card", "Deck", "DeckError", "NumberRef", "read_deck", "ResultError", "node_dof_weights",
           "read_eigenfrequencies", "read_steady_state", "read_storage", "INSTALL_HINT", "CcxError", "CcxMissing",
           "CcxTimeout", "ccx_executable", "run_ccx", "Segment", "segment_matrices"]
