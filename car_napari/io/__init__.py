"""Reading and writing images (DICOM with its windowing), and the sample data."""

from .dicom import read_dicom
from .images import DICOM_SUFFIXES, IMAGE_SUFFIXES, read_image, write_image

__all__ = ["DICOM_SUFFIXES", "IMAGE_SUFFIXES", "read_dicom", "read_image", "write_image"]
