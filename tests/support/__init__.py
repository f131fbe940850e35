"""Test-only helpers (``from tests.support.X import ...``): naive reference implementations the tests compare
the package's numerics against, and readers of files jnr writes (its code never reads them back)."""
