"""Helpers shared by the test modules: ``from helpers.meshfiles import write_off``."""
