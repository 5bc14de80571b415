"""Tools: replay, fault injection, benchmarks."""
