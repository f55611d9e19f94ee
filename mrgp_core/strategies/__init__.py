"""Search strategies behind one interface (:mod:`.base`: propose, evaluate, update, stop).

* :mod:`.paper`: the paper's adaptive MRGP loop (Table 2), its steps in :mod:`.table2`, its emulators in
  :mod:`.emulation` (the residuals, as the paper) and :mod:`.modal_emulation` (the modes, the default);
* :mod:`.polish`: least squares on the FE model after the paper's loop (the ``adaptive`` strategy);
* :mod:`.hybrid`: the default, Gauss-Newton with exact Jacobians from the nominal model and global cycles
  with the MRGP emulator when the residual is not noise (phases in :mod:`.hybrid_phases`, Gauss-Newton in
  :mod:`.gauss_newton`, the round counting in :mod:`.ledger`).
"""
