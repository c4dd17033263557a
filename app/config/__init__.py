"""Preset configuration: schema (frozen dataclasses, SI units), loading, validation, derived values."""
from .loader import ConfigError, dump, load, load_text, resolve_path
from .schema import Config

__all__ = ["Config", "ConfigError", "dump", "load", "load_text", "resolve_path"]
