# Transducer data types (spec 2.2): name -> (struct code, size in bytes, min, max).
# Shared by the board runtime and the host's descriptor parser, so both agree on the wire layout.
# bool travels as one byte (0/1): MicroPython's struct has no '?'.

DTYPES = {
    "int8_t": ("b", 1, -128, 127),
    "uint8_t": ("B", 1, 0, 255),
    "int16_t": ("h", 2, -32768, 32767),
    "uint16_t": ("H", 2, 0, 65535),
    "int32_t": ("i", 4, -2147483648, 2147483647),
    "uint32_t": ("I", 4, 0, 4294967295),
    "int64_t": ("q", 8, -9223372036854775808, 9223372036854775807),
    "uint64_t": ("Q", 8, 0, 18446744073709551615),
    "float": ("f", 4, None, None),
    "double": ("d", 8, None, None),
    "bool": ("B", 1, 0, 1),
}

FLOAT_TYPES = ("float", "double")
SIF_MAX_PAYLOAD = 255
TIMESTAMP_SIZE = 8


def sif_size(dtype, chan_count):
    return chan_count * (TIMESTAMP_SIZE + DTYPES[dtype][1])
