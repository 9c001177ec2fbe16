"""Transfer-measurement logs (four-electrode measurements on electrodes anywhere in a scene) and readers."""
from electrosense.validation.bench.transfer.log import (
    MAGIC,
    TransferLog,
    is_transfer_log,
    read_transfer_log,
    write_transfer_log,
)

__all__ = ["TransferLog", "read_transfer_log", "write_transfer_log", "is_transfer_log", "MAGIC"]
