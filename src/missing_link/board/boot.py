# Firmware updates over the link, with a way back: which firmware a board starts (main.py, the
# boot loader, asks here).  The update itself: update.py; the host's side: host/update.py;
# docs/hardware.md, "Updates over the link".
#
# Theory of operation
# -------------------
# A board's flash holds up to three whole firmwares (a runtime lib/mlboard/** and a board file
# board.py), in slots: "flash", the root, where `missing-link flash` puts one, and "a" and "b"
# under fw/, where updates go.  main.py, the boot loader (written by flash, never by an update),
# asks select() which slot to run, enter()s it and run()s it.
#
# The boot record names the slot that runs (active) and the one before it (previous), and says
# whether the active one is confirmed (state ok) or on trial (state trial: its count of starts,
# tries, the seconds trial_s it has to be confirmed, the fw.hash it must state).  It is kept in
# two files, fw/boot.0 and fw/boot.1, each ending in a check (SHA-256); a write goes to the file
# that does not hold the newest record, with the next seq, so a write cut short (torn, or not
# there at all) leaves the record before it, on any filesystem, without a rename.  No record:
# the flash slot.  `missing-link flash` removes fw/: the root runs again.
#
# An update, each step a J2A function (the host calls them in this order):
#   a2jFwBegin    the slot that does not run is emptied; the image's size, SHA-256 and the
#                 fw.hash its files make are noted
#   a2jFwStage    the image (MLFW1: path NUL size NUL bytes ... then an empty path), streamed
#                 into that slot's files chunk by chunk (a2jMany), hashed as it comes; after the
#                 last chunk, the SHA-256 of what came must be the one begun with, and the fw.hash
#                 of the files as they now are on the flash (read back) the one begun with
#   a2jFwSwitch   the record: active = the new slot, previous = the running one, trial, tries 0;
#                 the board restarts RESTART_US later (its reply has gone out by then)
#   a2jFwConfirm  called by the host once the new firmware completed a handshake and stated the
#                 fw.hash it was sent: state ok
# select() at the next start counts the trial's start (tries 1, written) and runs it.  Not
# confirmed within trial_s, or raising (main.py), the reason goes into the record (`why`) and
# the board restarts; a trial that started once already is not run again: select() writes the
# record back to the previous slot (ok; `rolled` and `why` say what happened) and runs that.
# A power cut anywhere: before the switch's record is whole, the old firmware runs (the slot it
# was staging into is emptied at the next begin); after it, the new one runs once and is
# confirmed or given up.  A firmware on trial takes no update until it is confirmed.
#
# MicroPython subset only.

import hashlib
import os
import sys

from .identity import hex_id

MAGIC = "ML-BOOT/1"
RECORDS = ("fw/boot.0", "fw/boot.1")
FIELDS = ("seq", "active", "previous", "state", "tries", "trial_s", "hash", "rolled", "why")
WHY_MAX = 120


def slot_dir(slot):
    # the slot's folder, relative to the board's root ("" or "fw/a/")
    return "" if slot == "flash" else "fw/%s/" % slot


def _check(body):
    return hex_id(hashlib.sha256(body).digest())[:16]


def encode_record(rec):
    lines = [MAGIC]
    for key in FIELDS:
        lines.append("%s %s" % (key, str(rec.get(key, "")).replace("\n", " ")))
    body = ("\n".join(lines) + "\n").encode()
    return body + ("check %s\n" % _check(body)).encode()


def parse_record(data):
    # the record in data, or None when it is not whole (a torn write, noise)
    try:
        text = data.decode()
    except ValueError:
        return None
    at = text.rfind("check ")
    if at < 0 or not text.startswith(MAGIC + "\n"):
        return None
    if text[at:] != "check %s\n" % _check(text[:at].encode()):
        return None
    rec = {}
    for line in text[:at].split("\n")[1:]:
        if line:
            key, _, value = line.partition(" ")
            rec[key] = value
    for key in FIELDS:
        if key not in rec:
            return None
    try:
        int(rec["seq"])
        int(rec["tries"])
        int(rec["trial_s"])
    except ValueError:
        return None
    return rec


def mkdirs(os_module, path):
    # every folder of path ("fw/a/lib/mlboard"), those there already kept
    at = ""
    for part in path.split("/"):
        if not part:
            continue
        at = at + "/" + part if at else part
        try:
            os_module.mkdir(at)
        except OSError:
            pass  # (there already: EEXIST; anything else fails at the first file)


def _is_dir(os_module, path):
    try:
        return bool(os_module.stat(path)[0] & 0x4000)
    except OSError:
        return False


def remove_tree(os_module, path):
    # path and everything under it; nothing there is fine
    if not _is_dir(os_module, path):
        try:
            os_module.remove(path)
        except OSError:
            pass
        return
    for name in os_module.listdir(path):
        remove_tree(os_module, path + "/" + name)
    os_module.rmdir(path)


class BootRecord:
    # The boot record in its two files (see the top): read() -> dict or None, write(rec).
    def __init__(self, os_module=None, opener=None):
        self.os = os if os_module is None else os_module
        self.open = open if opener is None else opener
        self._newest = -1  # which file holds the newest record read

    def read(self):
        best = None
        self._newest = -1
        for i in range(2):
            try:
                with self.open(RECORDS[i], "rb") as f:
                    rec = parse_record(f.read(2048))
            except OSError:
                rec = None
            if rec is not None and (best is None or int(rec["seq"]) > int(best["seq"])):
                best, self._newest = rec, i
        return best

    def write(self, rec):
        # rec with the next seq, into the file that does not hold the newest record
        now = self.read()
        rec = dict(rec)
        rec["seq"] = str(int(now["seq"]) + 1 if now is not None else 1)
        mkdirs(self.os, "fw")
        with self.open(RECORDS[1 if self._newest == 0 else 0], "wb") as f:
            f.write(encode_record(rec))
        return rec


class Boot:
    # What select() chose: the slot to run, and whether it runs on trial (trial_s to be
    # confirmed); note: what the firmware says at start (went back, and why).
    def __init__(self, slot, trial=False, trial_s=0, note="", rolled=""):
        self.slot = slot
        self.trial = trial
        self.trial_s = trial_s
        self.note = note
        self.rolled = rolled


def _runnable(os_module, slot):
    d = slot_dir(slot)
    for path in (d + "board.py", d + "lib/mlboard/firmware.py"):
        try:
            os_module.stat(path)
        except OSError:
            return False
    return True


def select(store=None, os_module=None):
    # Which slot runs at this start (see the top); the record written where the start counts.
    os_module = os if os_module is None else os_module
    store = BootRecord(os_module) if store is None else store
    rec = store.read()
    if rec is None or rec["active"] == "flash" and rec["state"] == "ok":
        return Boot("flash")
    active = rec["active"]
    if rec["state"] == "trial":
        if not _runnable(os_module, active):
            return _back(store, rec, "slot %s holds no whole firmware" % active)
        if int(rec["tries"]) < 1:
            try:
                store.write(dict(rec, tries="1"))
            except OSError as e:  # a start that cannot be counted could loop: not run
                return _back(store, rec, "its start could not be counted (%s)" % e)
            return Boot(active, True, int(rec["trial_s"]))
        return _back(store, rec, rec["why"] or "it was not confirmed")
    if not _runnable(os_module, active):
        return Boot("flash", note="slot %s has no firmware: the flash slot runs" % active)
    return Boot(active)


def _back(store, rec, why):
    # the trial given up: the previous slot runs, the record says so
    back = dict(rec, active=rec["previous"], previous=rec["active"], state="ok", tries="0")
    back["rolled"] = rec["active"]
    back["why"] = why[:WHY_MAX]
    try:
        store.write(back)
    except OSError:
        pass  # (the trial is not run again this start all the same)
    note = "went back from the firmware in slot %s: %s" % (rec["active"], back["why"])
    return Boot(back["active"], note=note, rolled=rec["active"])


def _slot_paths(root):
    out = []
    for slot in ("a", "b"):
        base = root + "/" + slot_dir(slot)
        out += [base.rstrip("/"), base + "lib"]
    return out


def enter(boot, root=None):
    # The chosen slot's runtime and board file are what `import mlboard`, `import board` find
    # from now on (what was imported of another slot is forgotten).
    if root is None:
        root = os.getcwd()
    root = root.rstrip("/")
    for path in _slot_paths(root):
        while path in sys.path:
            sys.path.remove(path)
    base = root + "/" + slot_dir(boot.slot)
    sys.path.insert(0, base + "lib")
    sys.path.insert(0, base.rstrip("/") or "/")
    for name in list(sys.modules):
        if name == "board" or name == "mlboard" or name.startswith("mlboard."):
            del sys.modules[name]


def crashed(boot, e, store=None):
    # The firmware raised.  On trial: why, into the record (the board restarts and goes back);
    # True when it should restart.
    if not boot.trial:
        return False
    store = BootRecord() if store is None else store
    try:
        rec = store.read()
        if rec is not None and rec["state"] == "trial":
            why = "the new firmware raised %s: %s" % (type(e).__name__, e)
            store.write(dict(rec, why=why[:WHY_MAX]))
    except OSError:
        pass
    return True
