"""Plain file input and output for the tasks (no Prefect here).

Modules
-------
measured
    The measured-FRF format: ``read_measured``, ``write_measured``,
    ``MeasuredFRF`` and ``MeasuredDataError``; ``python -m tasks.io.measured
    PATH`` validates a file from the command line.

Import from the modules themselves (``from tasks.io.measured import
read_measured``); this package re-exports nothing, so that ``python -m
tasks.io.measured`` does not import the module twice.
"""
