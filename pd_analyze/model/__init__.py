"""The model: plain data every layer shares.

The field registry (`fields`), fixed structures declared as data (`layout`), value tables of the
network layers (`values`) and of PROFIdrive (`pd_values`), the rule registry with the Finding record
(`rules`). It imports nothing from the layers above it.
"""
