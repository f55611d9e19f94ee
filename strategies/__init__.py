"""Search strategies behind one interface (:mod:`.base`: propose, evaluate, update, stop), above both cores.

The strategies use the FE side (:mod:`fe_core`: residual statistics, the effect library) and the emulator
(:mod:`mrgp_core`), which know nothing of each other:

* :mod:`.paper`: the paper's adaptive MRGP loop (Table 2), its steps in :mod:`.table2`, its emulators in
  :mod:`.emulation` (the residuals, as the paper) and :mod:`.modal_emulation` (the modes, the default);
* :mod:`.polish`: least squares on the FE model after the paper's loop (the ``adaptive`` strategy);
* :mod:`.hybrid`: the default, Gauss-Newton with exact Jacobians from the nominal model and global cycles
  with the MRGP emulator when the residual is not noise (phases in :mod:`.hybrid_phases`, Gauss-Newton in
  :mod:`.gauss_newton`, the round counting in :mod:`.ledger`);
* :mod:`.modal_paper`: the paper's loop on measured modes; :mod:`.modal_fit`: the modal Gauss-Newton fit, a
  callback optimiser made ask-tell by :mod:`.callback` (any such optimiser in a worker thread);
* :mod:`.closure_emulator`: the MRGP over (alpha, effect position, log size) for the closure's first round.
"""
