# Firmware updates over the link: the board's side of an update, and the firmware's loop on a
# device (run(), what main.py starts).  Which slot starts, the boot record, going back: boot.py
# (its "Theory of operation" says the whole sequence); the host's side: host/update.py.
#
# Theory of operation
# -------------------
# attach() gives a runtime an UpdateReceiver, whose J2A functions are the update's steps:
#   a2jFwInfo     (a blob of key NUL value NUL, spec 1.8) the slot that runs, its state, the
#                 room on the flash, the board file's mcu, the last staging error, `rolled`/`why`
#   a2jFwBegin    key NUL value NUL: size, sha256 (hex), fw.hash, and key_file (a key the new
#                 board file's link reads: it must be on the flash already) -> the slot it stages
#                 into; refused while the running firmware is on trial
#   a2jFwStage    (a2jMany write) the image, at increasing offsets; ImageWriter writes its files
#                 as the bytes come; the last chunk checks size, SHA-256 and the files' fw.hash
#   a2jFwSwitch   <H trial_s>: the boot record names the staged slot, on trial; the board restarts
#   a2jFwConfirm  the firmware on trial is confirmed (the host completed its handshake)
# A step that fails says why (its reply, a2jFwInfo's `error`, the log) and forgets the staging:
# a new begin starts over.  due(now) is the shell's to ask between turns: the restart after a
# switch, or a trial not confirmed in time (its why noted first); the shell then restarts the
# board (GuardLink on a device, the simulator's reboot).
#
# MicroPython subset only.

import hashlib
import os
import struct
import sys

from .boot import BootRecord, mkdirs, remove_tree, slot_dir
from .identity import hex_id, tree_hash
from .log import INFO, WARN

IMAGE_MAGIC = b"MLFW1\n"
MAX_IMAGE = 4 << 20
MAX_FIELD = 96  # a path or a size in the image
RESTART_US = 200000
TRIAL_S = (5, 3600)  # what a2jFwSwitch takes
REFUSED = 0xFF


def check_path(path):
    # a file an image may put in a slot: the runtime's .py files and the board file
    ok = path == "board.py" or (path.startswith("lib/mlboard/") and path.endswith(".py"))
    for c in path:
        if not (c.isalpha() or c.isdigit() or c in "_./-"):
            ok = False
    if not ok or ".." in path or "//" in path:
        raise ValueError("the image names a file %r a slot does not take" % path)
    return path


class ImageWriter:
    # An MLFW1 image, fed in pieces, written as files under base: feed(data), then finish().
    HEAD, PATH, SIZE, DATA, END = range(5)

    def __init__(self, base, os_module, opener):
        self.base = base
        self.os = os_module
        self.open = opener
        self.state = self.HEAD
        self.field = bytearray()
        self.path = ""
        self.left = 0
        self.f = None
        self.files = 0

    def feed(self, data):
        mv = memoryview(data)
        i = 0
        while i < len(data):
            if self.state == self.DATA:
                k = min(self.left, len(data) - i)
                self.f.write(mv[i : i + k])
                i += k
                self.left -= k
                if not self.left:
                    self._close()
                continue
            if self.state == self.END:
                raise ValueError("bytes after the image's end")
            b = data[i]
            i += 1
            if self.state == self.HEAD:
                self.field.append(b)
                if len(self.field) == len(IMAGE_MAGIC):
                    if bytes(self.field) != IMAGE_MAGIC:
                        raise ValueError("not an MLFW1 image")
                    self.field = bytearray()
                    self.state = self.PATH
            elif b:
                if len(self.field) >= MAX_FIELD:
                    raise ValueError("an image field over %d bytes" % MAX_FIELD)
                self.field.append(b)
            else:
                self._field(bytes(self.field).decode())
                self.field = bytearray()

    def _field(self, text):
        if self.state == self.PATH:
            if not text:
                self.state = self.END
                return
            self.path = check_path(text)
            self.state = self.SIZE
            return
        if not text.isdigit() or int(text) > MAX_IMAGE:
            raise ValueError("%s: size %r" % (self.path, text))
        self.left = int(text)
        full = self.base + self.path
        mkdirs(self.os, full[: full.rfind("/")])
        self.f = self.open(full, "wb")
        self.state = self.DATA
        if not self.left:
            self._close()

    def _close(self):
        self.f.close()
        self.f = None
        self.files += 1
        self.state = self.PATH

    def finish(self):
        if self.state != self.END:
            raise ValueError("the image ended inside a file")

    def abort(self):
        if self.f is not None:
            try:
                self.f.close()
            except OSError:
                pass
            self.f = None


def _props(payload):
    # key NUL value NUL ... (spec 1.8) -> dict
    parts = bytes(payload).split(b"\0")
    out = {}
    for i in range(0, len(parts) - 1, 2):
        out[parts[i].decode()] = parts[i + 1].decode()
    return out


def _is_hex(text, n):
    return len(text) == n and all(c in "0123456789abcdef" for c in text)


class UpdateReceiver:
    # The update's J2A functions on one runtime (see the top); boot: what select() chose.
    def __init__(self, rt, board, boot, store=None, os_module=None, opener=None):
        self.rt = rt
        self.board = board
        self.boot = boot
        self.os = os if os_module is None else os_module
        self.open = open if opener is None else opener
        self.store = BootRecord(self.os, self.open) if store is None else store
        self.started_us = rt.clock()
        self.confirmed = not boot.trial
        self.restart_us = None
        self.restart_why = ""
        self.restart_level = INFO  # (a trial given up: WARN)
        self.error = ""
        self.writer = None
        self.target = ""
        self.staged = False
        rt.add_blob_function("a2jFwInfo", self.info_blob)
        rt.add_function("a2jFwBegin", self._begin)
        rt.add_many_function("a2jFwStage", self._stage)
        rt.add_function("a2jFwSwitch", self._switch)
        rt.add_function("a2jFwConfirm", self._confirm)
        if boot.note:
            rt.log.line(WARN if boot.rolled else INFO, boot.note)

    # ---- what the host reads -------------------------------------------------------------
    def info_blob(self):
        rec = self._record()
        info = [
            ("update", "1"),
            ("slot", self.boot.slot),
            ("state", "trial" if not self.confirmed else "ok"),
            ("trial_s", str(self.boot.trial_s)),
            ("previous", rec.get("previous", "")),
            ("rolled", rec.get("rolled", "")),
            ("why", rec.get("why", "")),
            ("staged", self.target if self.staged else ""),
            ("error", self.error),
            ("room", self._room()),
            ("mcu", str(self.board.get("mcu", "rp2040"))),
            ("platform", sys.platform),
        ]
        return b"".join(k.encode() + b"\0" + v.encode() + b"\0" for k, v in info)

    def _record(self):
        try:
            return self.store.read() or {}
        except OSError:
            return {}

    def _room(self):
        # bytes free on the flash, with what the slot an update empties holds ("": not known)
        try:
            st = self.os.statvfs("/" if sys.platform != "webassembly" else ".")
            free = st[0] * st[4]
        except (AttributeError, OSError):
            return ""
        return str(free + _tree_size(self.os, slot_dir(self._other()).rstrip("/")))

    def _other(self):
        return "b" if self.boot.slot == "a" else "a"

    # ---- the steps -----------------------------------------------------------------------
    def _refuse(self, why):
        self._forget()
        self.error = why
        self.rt.log.line(WARN, "update refused: %s" % why)
        return REFUSED, why.encode()[:200]

    def _forget(self):
        if self.writer is not None:
            self.writer.abort()
        self.writer = None
        self.staged = False

    def _begin(self, payload):
        try:
            p = _props(payload)
        except (ValueError, IndexError):
            return self._refuse("a2jFwBegin takes key NUL value NUL pairs")
        if not self.confirmed:
            return self._refuse("the running firmware is on trial: it takes no update before "
                                "it is confirmed")  # fmt: skip
        size, sha, fw_hash = p.get("size", ""), p.get("sha256", ""), p.get("fw.hash", "")
        if not size.isdigit() or not 0 < int(size) <= MAX_IMAGE:
            return self._refuse("size %r: expected 1..%d bytes" % (size, MAX_IMAGE))
        if not _is_hex(sha, 64) or not _is_hex(fw_hash, 16):
            return self._refuse("sha256 (64 hex digits) and fw.hash (16) are needed")
        key = p.get("key_file", "")
        if key and not _exists(self.os, key):
            why = "the new board file's link reads the key %s, which this board does not have"
            return self._refuse(why % key + " (flash --key puts it there, over USB)")
        self._forget()
        self.target = self._other()
        base = slot_dir(self.target)
        try:
            remove_tree(self.os, base.rstrip("/"))
            mkdirs(self.os, base)
        except OSError as e:
            return self._refuse("cannot empty slot %s: %s" % (self.target, e))
        self.size, self.got = int(size), 0
        self.want_sha, self.want_hash = sha, fw_hash
        self.sha = hashlib.sha256()
        self.writer = ImageWriter(base, self.os, self.open)
        self.error = ""
        self.rt.log.line(INFO, "update: staging %d bytes into slot %s" % (self.size, self.target))
        return 0, self.target.encode()

    def _stage(self, is_write, is_last, offset, data):
        if not is_write:
            return REFUSED, True, b""
        if self.writer is None:
            self._refuse("a2jFwStage without a2jFwBegin")
            return REFUSED, True, b""
        if offset != self.got or self.got + len(data) > self.size:
            self._refuse("a chunk at offset %d (+%d), expected %d of %d bytes"
                         % (offset, len(data), self.got, self.size))  # fmt: skip
            return REFUSED, True, b""
        try:
            self.sha.update(data)
            self.writer.feed(data)
            self.got += len(data)
            if is_last:
                self._finish()
        except (OSError, ValueError) as e:
            self._refuse("staging into slot %s: %s" % (self.target, e))
            return REFUSED, True, b""
        return 0, is_last, b""

    def _finish(self):
        if self.got != self.size:
            raise ValueError("%d bytes came, %d were begun with" % (self.got, self.size))
        if hex_id(self.sha.digest()) != self.want_sha:
            raise ValueError("the image's SHA-256 is not the one begun with")
        self.writer.finish()
        base = slot_dir(self.target)
        got = tree_hash(base + "lib/mlboard", base + "board.py")
        if got != self.want_hash:  # what the flash holds now, read back
            raise ValueError("the files written hash to %s, not %s" % (got, self.want_hash))
        files = self.writer.files
        self.writer = None
        self.staged = True
        self.rt.log.line(INFO, "update: %d files staged in slot %s (fw.hash %s)"
                         % (files, self.target, got))  # fmt: skip

    def _switch(self, payload):
        if not self.staged:
            return self._refuse("a2jFwSwitch without a whole staged update")
        if len(payload) != 2:
            return self._refuse("a2jFwSwitch takes <H trial_s>")
        trial_s = struct.unpack("<H", payload)[0]
        if not TRIAL_S[0] <= trial_s <= TRIAL_S[1]:
            return self._refuse("trial_s %d: expected %d..%d" % (trial_s, TRIAL_S[0], TRIAL_S[1]))
        rec = {"active": self.target, "previous": self.boot.slot, "state": "trial",
               "tries": "0", "trial_s": str(trial_s), "hash": self.want_hash, "rolled": "",
               "why": ""}  # fmt: skip
        try:
            self.store.write(rec)
        except OSError as e:
            return self._refuse("cannot write the boot record: %s" % e)
        self.staged = False
        self.restart_us = self.rt.clock() + RESTART_US
        self.restart_why = "restarting into the new firmware (slot %s)" % self.target
        return 0, b""

    def _confirm(self, payload):
        if self.confirmed:
            return 0, b"ok"
        try:
            rec = self.store.read()
            if rec is not None and rec["state"] == "trial" and rec["active"] == self.boot.slot:
                self.store.write(dict(rec, state="ok", tries="0", why=""))
        except OSError as e:
            return REFUSED, ("cannot write the boot record: %s" % e).encode()[:200]
        self.confirmed = True
        self.rt.log.line(INFO, "the firmware in slot %s is confirmed" % self.boot.slot)
        return 0, b"confirmed"

    # ---- for the shell -------------------------------------------------------------------
    def due(self, now_us):
        # Why the board should restart now (None: it should not): after a switch, or a trial
        # not confirmed within its time (noted in the record first: it goes back at the start).
        if self.restart_us is not None and now_us >= self.restart_us:
            return self.restart_why
        if self.confirmed or now_us - self.started_us < self.boot.trial_s * 1000000:
            return None
        why = "no host confirmed it within %d s" % self.boot.trial_s
        try:
            rec = self.store.read()
            if rec is not None and rec["state"] == "trial":
                self.store.write(dict(rec, why=why))
        except OSError:
            pass
        self.confirmed = True  # (said once: the restart follows)
        self.restart_level = WARN
        self.restart_us = now_us
        self.restart_why = "the new firmware was not confirmed: %s; restarting" % why
        return self.restart_why

    def before_restart(self, why):
        # what the board drives goes safe, the host hears why (a trial given up: a warning)
        if self.rt.failsafe is not None:
            self.rt.failsafe.stop(why)
        self.rt.log.line(self.restart_level, why)


def _exists(os_module, path):
    try:
        os_module.stat(path)
        return True
    except OSError:
        return False


def _tree_size(os_module, path):
    try:
        st = os_module.stat(path)
    except OSError:
        return 0
    if not st[0] & 0x4000:
        return st[6]
    return sum(_tree_size(os_module, path + "/" + n) for n in os_module.listdir(path))


def attach(rt, board, boot):
    # the runtime takes updates (its UpdateReceiver: the shell asks it due() between turns)
    return UpdateReceiver(rt, board, boot)


class GuardLink:
    # The firmware's link on a device, and between its turns the updater's restarts: the board
    # restarts (machine.reset) when due() says so.
    def __init__(self, link, machine):
        self.link = link
        self.machine = machine
        self.updater = None
        if hasattr(link, "stats"):  # (a signed link: firmware.py shows what it dropped)
            self.stats = link.stats

    def read(self):
        upd = self.updater
        if upd is not None:
            why = upd.due(upd.rt.clock())
            if why:
                self._restart(upd, why)
        return self.link.read()

    def write(self, data):
        self.link.write(data)

    def wait(self, us):
        self.link.wait(us)

    def close(self):
        self.link.close()

    def _restart(self, upd, why):
        upd.before_restart(why)
        try:
            out = upd.rt.take_output()
            if out:
                self.link.write(out)
        except Exception:  # noqa: BLE001 - best effort: the board restarts all the same
            pass
        self.link.close()
        self.machine.reset()


def run(boot, machine):
    # The firmware in the slot boot.py chose, on a device (main.py): as firmware.main(), with
    # updates and the trial's restarts.
    from board import BOARD as board  # noqa: N811 - the slot's board file

    from .firmware import BreakIn, Firmware
    from .link import open_link

    link = GuardLink(open_link(board.get("link", {"kind": "usb"}), machine), machine)
    try:
        fw = Firmware(board, machine, link)
        link.updater = attach(fw.runtime, board, boot)
        fw.run()
    except BreakIn:
        print("missing-link firmware stopped: REPL")
    finally:
        link.close()
