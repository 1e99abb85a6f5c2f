"""Calibration of Ogden laws from rig force-displacement logs, built on :mod:`solver`.

Pipeline, one module per step: ``loaders`` (rig logs -> cycles) -> ``modulus`` (Young's
modulus per cycle) -> ``rates`` (strain-rate dependence per layer) -> ``fit`` (FE-coupled Ogden
fit per layer) -> ``discover`` (missing physics) -> ``export`` (parameter tables and cards);
``cli`` is the ``calib`` command.
"""
