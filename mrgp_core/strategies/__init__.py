"""Updating strategies that decide which FE runs to make next, one parallel round at a time.

* :mod:`.local_first`: the default candidate (issue 17) -- Gauss-Newton from the
  nominal model with parallel trial steps, and space-filling restarts when the
  local phase stalls above the noise.
"""

from .local_first import LocalFirstResult, local_first

__all__ = ["LocalFirstResult", "local_first"]
