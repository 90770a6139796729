"""Lie series and Taylor coefficients of vector fields given as heyoka expressions."""

from ..expr import Program, compile_expressions, compile_system
from .jets import taylor_coefficients, taylor_coefficients_raw
from .literal import lie_derivatives, literal_coefficients, literal_series_symbolic

__all__ = [
    "Program",
    "compile_expressions",
    "compile_system",
    "taylor_coefficients",
    "taylor_coefficients_raw",
    "lie_derivatives",
    "literal_coefficients",
    "literal_series_symbolic",
]
