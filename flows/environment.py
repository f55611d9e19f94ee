"""The process environment every command sets before Prefect is imported (an explicit environment wins).

* Offline and quiet: no analytics, no telemetry; Prefect's temporary local API given time to start on a busy
  2-core machine (its default is 20 s).
* One BLAS thread per process: the MRGP's small dense algebra is ~15x slower with OpenBLAS's default
  threading on 2 cores, and FE workers run in parallel anyway.
* The cores' own log lines (``fe_core``, ``mrgp_core``: a closure's steps, a forward selection's rounds, the
  posterior's rounds) reach the run's log and the Prefect UI beside the tasks' (``PREFECT_LOGGING_EXTRA_LOGGERS``),
  at INFO; outside a flow run they stay in the process (``PREFECT_LOGGING_TO_API_WHEN_MISSING_FLOW=ignore``).

Imported first by each command module (``flows/update.py``, ``report.py``, ``diagnose.py``, ``correlation.py``).
"""

from __future__ import annotations

import logging
import os

__all__ = ["CORE_LOGGERS"]

#: Loggers of the plain-numpy cores whose INFO lines belong in a run's log.
CORE_LOGGERS = ("fe_core", "mrgp_core")

for _key, _value in {"DO_NOT_TRACK": "1", "PREFECT_SERVER_ANALYTICS_ENABLED": "false",
                     "PREFECT_CLOUD_ENABLE_ORCHESTRATION_TELEMETRY": "false",
                     "PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS": "120",
                     "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
                     "PREFECT_LOGGING_EXTRA_LOGGERS": ",".join(CORE_LOGGERS),
                     # the cores also run outside a flow (tests, scripts): their lines then stay local
                     "PREFECT_LOGGING_TO_API_WHEN_MISSING_FLOW": "ignore"}.items():
    os.environ.setdefault(_key, _value)
for _name in CORE_LOGGERS:
    if logging.getLogger(_name).level == logging.NOTSET:
        logging.getLogger(_name).setLevel(logging.INFO)
