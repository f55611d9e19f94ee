"""Solvers on a :class:`fe_core.model.ParametricModel`: FRFs (direct and Krylov), their exact derivatives
(direct, Krylov, adjoint), Jacobians and sensitivities of the measured responses, and modes.

* :mod:`.frf`: the receptance at the sensors, direct solves and a block Krylov space;
* :mod:`.frf_derivatives`: derivatives of the FRF along parameter directions;
* :mod:`.adjoint`: reduced (adjoint) responses for many parameters at few outputs;
* :mod:`.sensitivity`: Jacobians of the measured channels and their log amplitudes, identifiability;
* :mod:`.modal`: natural frequencies and mode shapes.
"""
