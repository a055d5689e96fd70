"""Inverse-dynamics models behind one interface (train.models.base.Model)."""
