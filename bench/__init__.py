"""Benchmarks: run each as a module from the checkout, ``python -m bench.bench_<area>`` (``make bench`` runs all)."""
