"""Converters from published dataset layouts into the unified format, one module per source."""

from avdata.converters.base import (
    CONVERTERS,
    ConversionResult,
    ConvertConfig,
    Converter,
    Problem,
    Report,
    converter_class,
    run_conversion,
)

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
