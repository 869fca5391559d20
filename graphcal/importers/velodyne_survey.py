"""A light first pass over a Velodyne capture's data packets: what the model, the return mode and the time base
are decided on, gathered chunk by chunk in memory bounded whatever the capture's length (counts, and the packet
spacings' distinct values), then the decision (`layout`), checked against the packet rate."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from graphcal.common.errors import ConfigError, RecordingError
from graphcal.importers.value_counts import ValueCounts
from graphcal.importers.velodyne_packets import (
    BANK_FLAGS,
    DUAL_RETURN_MODE,
    LAYOUTS,
    LOWER_BLOCK,
    PRODUCT_IDS,
    HourUnwrap,
    PacketLayout,
)

_VLS128_PACKET_US = (150.0, 180.0)  # packet periods of VLS-128 firmware versions (160 to 173.3 us)


@dataclass
class PacketSurvey:
    """What the data packets of a whole capture say, packets given chunk after chunk in capture order.

    first_bad_flag: (packet, record, block, flag) of the first block flag that is none of BANK_FLAGS;
    first_host_s / first_us / last_us: the first packet's host clock time [s since 1970 UTC], the first and the last
    packet's timestamps [us past the first one's hour]; spacing_us: the positive steps between consecutive packet
    timestamps [us]."""

    n_packets: int = 0
    first_bad_flag: tuple[int, int, int, int] | None = None
    lower_blocks: bool = False  # HDL-64E lower-block flags seen
    four_banks: bool = False  # VLS-128 third and fourth bank flags seen
    products: np.ndarray = field(default_factory=lambda: np.zeros(256, dtype=np.int64))
    dual_mode: int = 0  # packets whose return-mode byte says dual return
    paired_blocks: int = 0  # packets whose blocks 0 and 2 have one azimuth (HDL-64E dual return)
    spacing_us: ValueCounts = field(default_factory=ValueCounts)
    first_host_s: float = float("nan")
    first_us: float = float("nan")
    last_us: float = float("nan")
    unwrap: HourUnwrap = field(default_factory=HourUnwrap)

    def add(self, packets: np.ndarray, host_time_s: np.ndarray, records: np.ndarray) -> np.ndarray:
        """Count the packets (structured PACKET array; host clock times, record indices for errors); their
        timestamps unwrapped past the first packet's hour [us]."""
        flags = packets["blocks"]["flag"]
        bad = ~np.isin(flags, BANK_FLAGS)
        if bad.any() and self.first_bad_flag is None:
            packet, block = (int(v) for v in np.argwhere(bad)[0])
            self.first_bad_flag = (self.n_packets + packet, int(records[packet]), block, int(flags[packet, block]))
        self.lower_blocks |= bool((flags == LOWER_BLOCK).any())
        self.four_banks |= bool(np.isin(flags, BANK_FLAGS[2:]).any())
        self.products += np.bincount(packets["product"], minlength=256)
        self.dual_mode += int(np.count_nonzero(packets["return_mode"] == DUAL_RETURN_MODE))
        azimuth = packets["blocks"]["azimuth"]
        self.paired_blocks += int(np.count_nonzero(azimuth[:, 0] == azimuth[:, 2]))
        time_us = self.unwrap(packets["stamp_us"])
        if len(time_us):
            if not self.n_packets:
                self.first_host_s, self.first_us = float(host_time_s[0]), float(time_us[0])
            steps = np.diff(np.concatenate([[self.last_us], time_us]) if self.n_packets else time_us)
            self.spacing_us.add(steps[steps > 0])
            self.last_us = float(time_us[-1])
        self.n_packets += len(packets)
        return time_us

    @property
    def banks(self) -> int:
        """Banks of 32 lasers the flags name: 4 (VLS-128), 2 (HDL-64E) or 1."""
        return 4 if self.four_banks else 2 if self.lower_blocks else 1

    @property
    def host_hour_utc_s(self) -> float:
        """The top of the first packet's hour by the capture host clock [s since 1970 UTC]."""
        return float(3600.0 * np.round((self.first_host_s - self.first_us * 1e-6) / 3600.0))


def layout(path: Path, survey: PacketSurvey, forced: str | None) -> tuple[PacketLayout, bool]:
    """The model (forced or from the packets) and the return mode, checked against the packet rate;
    RecordingError naming `path` when the packets are none of the models' or not the forced one's."""
    if survey.first_bad_flag is not None:
        packet, record, block, flag = survey.first_bad_flag
        raise RecordingError(path, f"data packet {packet} (record {record}), block {block}: flag 0x{flag:04X}",
                             expected="Velodyne block flags 0xEEFF, 0xDDFF, 0xCCFF or 0xBBFF")
    banks = survey.banks
    product = int(survey.products.argmax())
    if forced is not None and forced not in LAYOUTS:
        raise ConfigError(f"unknown Velodyne model {forced!r}; known: {', '.join(LAYOUTS)}")
    detected = {2: "HDL-64E", 4: "VLS-128"}.get(banks, PRODUCT_IDS.get(product))
    name = forced or detected
    if name is None:
        raise RecordingError(path, f"factory byte 0x{product:02X}", field="product",
                             expected=", ".join(f"0x{k:02X} ({m})" for k, m in PRODUCT_IDS.items())
                             + " or HDL-64E packets; force the model (--model) if the sensor is one of these")
    chosen = LAYOUTS[name]
    if chosen.blocks_per_column != banks:
        wanted = max(chosen.blocks_per_column, banks)
        what = {2: "HDL-64E lower-block flags (0xDDFF)", 4: "VLS-128 bank flags (0xCCFF, 0xBBFF)"}[wanted]
        raise RecordingError(path, f"model {name} forced, but the packets {'have' if banks == wanted else 'have no'} "
                                   f"{what}", expected=f"{detected or 'another model'} packets")
    dual = 2 * (survey.paired_blocks if banks == 2 else survey.dual_mode) > survey.n_packets  # the median vote
    if dual and name == "VLS-128":
        raise RecordingError(path, "VLS-128 dual-return packets", field="return_mode",
                             expected="single-return (strongest or last) VLS-128 data; dual return is not supported")
    spacing = survey.spacing_us.median()
    if name == "VLS-128" and _VLS128_PACKET_US[0] <= spacing <= _VLS128_PACKET_US[1]:
        # three firing sequences per packet; their period depends on the firmware (53.3 us in the
        # drivers, 2.89 us firing groups since firmware 5.2.3): taken from the packet rate
        chosen = replace(chosen, column_us=spacing / 3)
    if len(survey.spacing_us):
        expected = chosen.packet_us(dual)
        if abs(spacing / expected - 1.0) > 0.05:
            fits = [m for m, other in LAYOUTS.items() if abs(spacing / other.packet_us(dual) - 1.0) <= 0.05]
            why = f"the factory byte says 0x{product:02X}, " if forced is None and banks == 1 else ""
            raise RecordingError(path, f"{why}data packets come every {spacing:.1f} us, where a {name} "
                                       f"sends one every {expected:.1f} us",
                                 expected=(f"{fits[0]} data (old VLP-16 firmware writes 0x21, the HDL-32E byte): "
                                           f"force the model (--model {fits[0]})") if fits else
                                 "a continuous capture of one of " + ", ".join(LAYOUTS))
    return chosen, dual
