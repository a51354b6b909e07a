"""Measured engine data: a safe reader for NREL ADVISOR fuel-converter files and the engine type built on it.

    >>> from vpsim.engines import load_engine
    >>> engine = load_engine("FC_SI41_emis.m")  # doctest: +SKIP

:func:`read_m_file` evaluates ADVISOR ``.m`` data files with a small, safe MATLAB subset (nothing is run by
Python or MATLAB); :class:`MeasuredEngine` holds a fuel map in SI units and interpolates it.
"""

from ._matlab_base import InlineFunction, MValue
from .matlab import evaluate_m_text, read_m_file
from .measured import MeasuredEngine, load_engine

__all__ = ["InlineFunction", "MValue", "MeasuredEngine", "evaluate_m_text", "load_engine", "read_m_file"]
