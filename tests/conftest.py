import os

# Tests run on the CPU; keep XLA from grabbing every core's worth of threads per test.
os.environ.setdefault("JAX_PLATFORMS", "cpu")
# CLI tests run in-process: keep them from writing JAX's compilation cache to ~/.cache.
os.environ.setdefault("MJXSUITE_COMPILE_CACHE", "0")
