"""Photon passes: every method hands back the same camera-resolution photon map (irradiance, W/m²)."""

from .cisp import CISP, Ledger, PhotonSettings

__all__ = ["CISP", "Ledger", "PhotonSettings"]
