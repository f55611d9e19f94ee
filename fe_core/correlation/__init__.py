"""Test/analysis correlation of mode shapes (plain numpy): the modal assurance criterion (MAC), MAC-based
pairing of measured and model modes, frequency differences and the coordinate MAC (COMAC) per test DOF.

Conventions: a set of shapes is an array ``(n_modes, n_dofs)`` of real shapes at the *same* test DOFs, one
row per mode. Measured shapes may be unscaled (OMA) or of either sign: the MAC does not depend on the scale
or sign of either shape.

Example::

    from fe_core.correlation import mac_matrix, pair_modes, comac
    mac = mac_matrix(phi_test, phi_model)            # (n_test, n_model)
    pairs = pair_modes(mac, threshold=0.8)           # Pairing: pairs, unpaired test / model modes, messages
"""

from .mac import (Pairing, comac, frequency_differences, mac_matrix, modal_scale_factor, pair_modes,
                  pairing_report)

__all__ = ["mac_matrix", "modal_scale_factor", "pair_modes", "Pairing", "frequency_differences", "comac",
           "pairing_report"]
