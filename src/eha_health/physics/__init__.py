"""physics"""
from .compiled import use_keyed_cache

# before any kernel module is imported: their compiled code is cached by these sources (compiled.py)
use_keyed_cache()
