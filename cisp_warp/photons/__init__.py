"""Photon passes: every method hands back the same camera-resolution photon map (irradiance, W/m²)."""

from .base import Ledger, PhotonPass, PhotonSettings
from .cisp import CISP

__all__ = ["CISP", "Ledger", "PhotonPass", "PhotonSettings"]
