"""Helpers the tests share (``from support.harness import ...``): test modules never
import each other or conftest.py."""
