"""The built-in control laws, one module each (``LAW = Law(...)``).

The registry (:mod:`attitude_sil.core.control.registry`) finds every module
here by itself: adding a built-in law is adding a file. A law in another
package registers through the entry-point group ``attitude_sil.laws`` instead
(docs/writing-a-law.md).
"""
