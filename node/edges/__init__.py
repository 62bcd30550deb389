"""The I/O edges the live node and offline replay share: Zenoh sessions (``zenoh``) and each
bed's engine-history state file (``engine_file``). Neither owns them: ``node.live`` and ``replay``
both import this package, which imports neither (the contracts in pyproject.toml)."""
