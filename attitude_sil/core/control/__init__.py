"""The control laws: each one module (``laws/``), the :class:`~attitude_sil.core.control.law.Law` contract,
the registry (built-ins and the entry-point group ``attitude_sil.laws``), the bank that runs and swaps them,
the compiled helpers they share and the generated dispatch over them (docs/writing-a-law.md).
"""
