"""Reads key/value pairs back out of an ESP-IDF NVS partition image, for the tests.

Written from ESP-IDF's documented layout (nvs_flash, "NVS internals"), independently of
espdock and of Espressif's generator, so a test can check what actually reached the flash:
4096-byte pages, each a 32-byte header, a 32-byte bitmap of entry states (2 bits each:
11 empty, 10 written, 00 erased) and 126 entries of 32 bytes:
namespace index, type, span, chunk index, CRC32, 16-byte key, 8 bytes of data.
"""

from __future__ import annotations

import struct
import zlib

PAGE = 4096
ENTRIES = 126
ENTRY = 32
STATE_WRITTEN = 0b10
PAGE_UNINITIALIZED = 0xFFFFFFFF

_PRIMITIVES = {0x01: "<B", 0x11: "<b", 0x02: "<H", 0x12: "<h", 0x04: "<I", 0x14: "<i", 0x08: "<Q", 0x18: "<q"}
_STRING = 0x21


def _crc(data: bytes) -> int:
    return zlib.crc32(data, 0xFFFFFFFF) & 0xFFFFFFFF


def read_nvs(image: bytes) -> dict[str, dict[str, object]]:
    """{namespace: {key: value}} of every written entry; strings are str, integers int."""
    namespaces: dict[int, str] = {}
    raw: list[tuple[int, str, object]] = []
    for page_start in range(0, len(image) - PAGE + 1, PAGE):
        page = image[page_start : page_start + PAGE]
        if struct.unpack_from("<I", page, 0)[0] == PAGE_UNINITIALIZED:
            continue
        bitmap = page[32:64]
        index = 0
        while index < ENTRIES:
            state = (bitmap[index // 4] >> ((index % 4) * 2)) & 0b11
            entry = page[64 + index * ENTRY : 64 + (index + 1) * ENTRY]
            if state != STATE_WRITTEN:
                index += 1
                continue
            ns, kind, span, _chunk, crc = struct.unpack_from("<BBBBI", entry, 0)
            if crc != _crc(entry[0:4] + entry[8:32]):
                raise ValueError(f"page {page_start // PAGE}, entry {index}: header CRC mismatch")
            key = entry[8:24].split(b"\0", 1)[0].decode()
            if kind in _PRIMITIVES:
                value: object = struct.unpack_from(_PRIMITIVES[kind], entry, 24)[0]
            elif kind == _STRING:
                size, _reserved, data_crc = struct.unpack_from("<HHI", entry, 24)
                data = page[64 + (index + 1) * ENTRY : 64 + (index + 1) * ENTRY + size]
                if _crc(data) != data_crc:
                    raise ValueError(f"{key}: data CRC mismatch")
                value = data.rstrip(b"\0").decode()
            else:
                value = entry[24:32]
            if ns == 0:  # namespace definitions: key -> index
                namespaces[int(value)] = key
            else:
                raw.append((ns, key, value))
            index += max(span, 1)
    result: dict[str, dict[str, object]] = {}
    for ns, key, value in raw:
        result.setdefault(namespaces.get(ns, f"#{ns}"), {})[key] = value
    return result
