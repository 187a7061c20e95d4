"""The gyrocal wearable's BLE protocol: UUIDs, the GATT layout, and the binary encodings.

Both sides import this package: the client (``server.link``) and the simulated wearable
(``mock_device``). It depends on numpy only. The specification is docs/protocol.md. Commercial wearables'
public protocols are in ``wearable_protocol.vendors`` (docs/protocol.md, "Commercial wearables' protocols").
"""

from .codec import (
    CLOCK_MODULUS,
    CONFIG_SIZE,
    HEADER_SIZE,
    IDENTIFY_MAX_S,
    PROTOCOL_VERSION,
    SAMPLE_SIZE,
    SEQ_MODULUS,
    Command,
    DecodeError,
    DeviceConfig,
    DeviceState,
    Opcode,
    Packet,
    PacketFlags,
    Status,
    StatusReply,
    decode_packet,
    encode_packet,
    max_samples_per_packet,
    quantize,
    samples_per_packet,
)
from .gatt import (
    Central,
    CharacteristicSpec,
    ConnectionDropped,
    GattError,
    GattPeripheral,
    PeripheralUnavailable,
    ServiceSpec,
)
from .held_calibration import HeldCalibration, decode_slot, encode_slot
from .layout import WEARABLE_SERVICES
from .power_up import POWER_UP_SIZE, PowerUp, PowerUpFlags
from .sensor import (
    ACCEL_SENSITIVITY_LSB_PER_G,
    DEFAULT_ACCEL_RANGE_G,
    DEFAULT_GYRO_FULL_SCALE_DPS,
    DEFAULT_MTU,
    DEFAULT_RATE_HZ,
    GYRO_SENSITIVITY_LSB_PER_DPS,
    SUPPORTED_RATES_HZ,
    rate_supported,
)
from .uuids import (
    BATTERY_LEVEL_CHAR,
    BATTERY_SERVICE,
    CCCD_DESCRIPTOR,
    DEVICE_INFORMATION_SERVICE,
    FIRMWARE_REVISION_CHAR,
    IMU_CALIBRATION_CHAR,
    IMU_CONFIG_CHAR,
    IMU_CONTROL_CHAR,
    IMU_DATA_CHAR,
    IMU_POWER_UP_CHAR,
    IMU_SERVICE,
    MANUFACTURER_NAME_CHAR,
    MODEL_NUMBER_CHAR,
    SERIAL_NUMBER_CHAR,
    USER_DESCRIPTION_DESCRIPTOR,
    sig_uuid,
)

__all__ = [name for name in dir() if not name.startswith("_")]
