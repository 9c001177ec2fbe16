"""Transfer-measurement logs (four-electrode measurements on electrodes anywhere in a scene) and readers."""
from .log import TransferLog, read_transfer_log, write_transfer_log, is_transfer_log, MAGIC

__all__ = ["TransferLog", "read_transfer_log", "write_transfer_log", "is_transfer_log", "MAGIC"]
