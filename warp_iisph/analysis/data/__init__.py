"""Experimental reference data (CSV) shipped with the package."""
