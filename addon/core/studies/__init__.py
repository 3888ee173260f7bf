"""Experiments and benchmarks built on the whole core: the paper protocol, speed figures."""
