"""The built-in attitude estimators, one module each (``ESTIMATOR = Estimator(...)``).

The registry (:mod:`attitude_sil.core.sensing.registry`) finds every module
here by itself: adding a built-in filter is adding a file. A filter in another
package registers through the entry-point group ``attitude_sil.estimators``
instead (docs/sensors.md).
"""
