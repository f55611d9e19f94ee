"""``python -m benchmarks.headline``: see the package's docstring."""

from benchmarks.headline import main

raise SystemExit(main())
