"""Converters from published dataset layouts into the unified format, one module per source."""

from avdata.converters.base import (
    CONVERTERS,
    ConversionResult,
    ConvertConfig,
    Converter,
    Report,
    converter_class,
    run_conversion,
)
from avdata.executors.scenes import Problem

__all__ = [
    "CONVERTERS",
    "ConversionResult",
    "ConvertConfig",
    "Converter",
    "Problem",
    "Report",
    "converter_class",
    "run_conversion",
]
