"""Reading images: DICOM with its windowing, and the sample data."""

from .dicom import read_dicom

__all__ = ["read_dicom"]
