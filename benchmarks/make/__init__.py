"""Data generators: each writes the files of ``data/`` it names (measured data from an independent model or a
finer mesh, example model files), so ``benchmarks/`` itself holds measurements. Run them as
``python -m benchmarks.make.<name>``; the data they wrote are committed, so nothing needs them to run."""


def parse_no_options(module: str, doc: str | None) -> None:
    """The command line of a generator that takes no options: ``--help`` prints its docstring and exits
    before anything is written; anything else given is refused (exit 2)."""
    import argparse

    argparse.ArgumentParser(prog=f"python -m {module}", description=(doc or "").split("\n\n")[0],
                            epilog="Takes no options; writes the files named above.").parse_args()
