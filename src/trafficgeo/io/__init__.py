"""Readers and writers; :mod:`trafficgeo.io.atomic` is a leaf module every layer may use."""
