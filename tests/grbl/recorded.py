"""grbl 1.1h exchanges, written from grbl's documentation (interface.md, commands.md,
settings.md, jogging.md and the doc/csv tables), one per behaviour the front implements.

The fake machine moves at the programmed feed with no acceleration: ``G1X10F600`` takes
one second; rapids go at 3000 mm/min; a hold takes 50 ms to come to rest; homing 0.3 s.
"""

from __future__ import annotations

from tests.grbl.conformance import Do, Exchange, Expect, Send, Wait
from tests.grbl.harness import Bench

from usbmotion.grbl.interface import Fault

BANNER = b"\r\nGrbl 1.1h ['$' for help]\r\n"
UNLOCK = b"[MSG:'$H'|'$X' to unlock]\r\n"
OK = b"ok\r\n"
Z3 = "0.000,0.000,0.000"


def report(state: str, mpos: str = Z3, *, bf: str = "15,128", fs: str = "0,0",
           extra: str = "", fe: str = Z3) -> bytes:
    """A status report as the front writes it (``extra``: fields between FS and FE)."""
    return f"<{state}|MPos:{mpos}|Bf:{bf}|FS:{fs}{extra}|FE:{fe}>\r\n".encode()


SETTINGS = (b"$0=10\r\n$1=255\r\n$2=0\r\n$3=0\r\n$4=0\r\n$5=0\r\n$6=0\r\n$10=3\r\n"
            b"$11=0.010\r\n$12=0.002\r\n$13=0\r\n$20=0\r\n$21=0\r\n$22=1\r\n$23=0\r\n"
            b"$24=25.000\r\n$25=500.000\r\n$26=250\r\n$27=1.000\r\n$30=1000\r\n$31=0\r\n"
            b"$32=0\r\n$100=1000.000\r\n$101=1000.000\r\n$102=1000.000\r\n"
            b"$110=3000.000\r\n$111=3000.000\r\n$112=3000.000\r\n$120=500.000\r\n"
            b"$121=500.000\r\n$122=500.000\r\n$130=300.000\r\n$131=300.000\r\n"
            b"$132=300.000\r\nok\r\n")

PARAMETERS = (b"[G54:0.000,0.000,0.000]\r\n[G55:0.000,0.000,0.000]\r\n"
              b"[G56:0.000,0.000,0.000]\r\n[G57:0.000,0.000,0.000]\r\n"
              b"[G58:0.000,0.000,0.000]\r\n[G59:0.000,0.000,0.000]\r\n"
              b"[G28:0.000,0.000,0.000]\r\n[G30:0.000,0.000,0.000]\r\n"
              b"[G92:0.000,0.000,0.000]\r\n[TLO:0.000]\r\n[PRB:0.000,0.000,0.000:0]\r\nok\r\n")

WCO0 = f"|WCO:{Z3}"
OV100 = "|Ov:100,100,100"


def _fault_on_line_3(bench: Bench) -> None:
    bench.machine.fault_on_line = (3, Fault(1, "following error 2.000 mm over 1.000 mm",
                                      axis="Y", line_number=3))


def _probe_fault_on_line_2(bench: Bench) -> None:
    bench.machine.fault_on_line = (2, Fault(4, "probe: not in the expected state",
                                            line_number=2))


def _homing_fails(bench: Bench) -> None:
    bench.machine.homing_fails = True


def _press_x_and_z_limits(bench: Bench) -> None:
    bench.machine.limit_pins = frozenset("XZ")


def _connect(bench: Bench) -> None:
    bench.front.connect()


def _discard(bench: Bench) -> None:
    bench.take()


def _dropped_33(bench: Bench) -> None:
    statistics = bench.front.statistics
    assert (statistics.max_rx_bytes, statistics.dropped_rx_bytes) == (128, 33), statistics


EXCHANGES: tuple[Exchange, ...] = (
    # ---- start-up, banner, help
    Exchange("banner on connect, in alarm while not homed", homed=False, steps=(
        Expect(BANNER + UNLOCK),)),
    Exchange("banner on connect, no alarm when homing is off", homed=False,
             machine={"homing": False}, steps=(Expect(BANNER),)),
    Exchange("$ prints the help line", steps=(
        Send(b"$\n"),
        Expect(b"[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]\r\n"
               + OK),)),
    Exchange("an empty line and a comment-only line are ok", steps=(
        Send(b"\n"), Send(b"(just a comment)\n"), Send(b"; another\n"),
        Expect(OK + OK + OK),)),
    Exchange("CR and LF each end a line: CRLF is two lines, two oks", steps=(
        Send(b"G21\r\n"), Expect(OK + OK),)),
    Exchange("lower case, spaces and comments are pre-parsed away", steps=(
        Send(b"g0 x1 (move) y2\n"), Wait(0.2),
        Send(b"?"), Expect(OK + report("Idle", "1.000,2.000,0.000", extra=WCO0)),)),

    # ---- $ queries
    Exchange("$$ prints every setting, then ok", steps=(Send(b"$$\n"), Expect(SETTINGS))),
    Exchange("$# prints the parameters, then ok", steps=(Send(b"$#\n"), Expect(PARAMETERS))),
    Exchange("$G prints the parser state", steps=(
        Send(b"$G\n"), Expect(b"[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]\r\n" + OK),
        Send(b"G91 G1 F500\n"), Send(b"$G\n"),
        Expect(OK + b"[GC:G1 G54 G17 G21 G91 G94 M5 M9 T0 F500 S0]\r\n" + OK),)),
    Exchange("$I prints version and options; $I= stores the text", steps=(
        Send(b"$I\n"), Expect(b"[VER:1.1h.20190825:]\r\n[OPT:VN*$#,15,128]\r\n" + OK),
        Send(b"$I=mill\n"), Send(b"$I\n"),
        Expect(OK + b"[VER:1.1h.20190825:MILL]\r\n[OPT:VN*$#,15,128]\r\n" + OK),)),
    Exchange("$N lists start-up lines; $N0= stores one; it runs after a reset", steps=(
        Send(b"$N\n"), Expect(b"$N0=\r\n$N1=\r\n" + OK),
        Send(b"$N0=G20 G54 G17\n"), Send(b"$N\n"),
        Expect(OK + b"$N0=G20G54G17\r\n$N1=\r\n" + OK),
        Send(b"\x18"), Expect(BANNER + b">G20G54G17:ok\r\n"),
        Send(b"$N2=G20\n"), Expect(b"error:3\r\n"),)),
    Exchange("malformed $ commands are error:3; an unknown letter reads as a bad setting "
             "number, error:2", steps=(
        Send(b"$Q\n"), Send(b"$$$\n"), Send(b"$X1\n"), Send(b"$HZ\n"),
        Expect(b"error:2\r\n" + b"error:3\r\n" * 3),)),

    # ---- settings
    Exchange("$N=value writes a mapped setting", steps=(
        Send(b"$110=2000\n"), Expect(OK),
        Send(b"$$\n"), Expect(SETTINGS.replace(b"$110=3000.000", b"$110=2000.000")),)),
    Exchange("setting errors: negative 4, bad number 2, unknown 3, soft limits need homing 10",
             machine={"homing": False}, homed=False, steps=(
        Expect(BANNER),
        Send(b"$110=-1\n"), Send(b"$110=\n"), Send(b"$99=1\n"), Send(b"$20=1\n"),
        Expect(b"error:4\r\nerror:2\r\nerror:3\r\nerror:10\r\n"),)),
    Exchange("a not-applicable setting: written unchanged ok, changed error:3 with why", steps=(
        Send(b"$0=10\n"), Expect(OK),
        Send(b"$0=5\n"),
        Expect(b"[MSG:$0 does not apply here: step pulse time: servo axes take no step "
               b"pulses]\r\nerror:3\r\n"),)),
    Exchange("$10=1 drops Bf; $10=0 reports WPos", steps=(
        Send(b"$10=1\n"), Send(b"?"),
        Expect(OK + f"<Idle|MPos:{Z3}|FS:0,0{WCO0}|FE:{Z3}>\r\n".encode()),
        Send(b"$10=0\n"), Send(b"G92X-5\n"), Send(b"?"),
        Expect(OK + OK + b"<Idle|WPos:-5.000,0.000,0.000|FS:0,0|WCO:5.000,0.000,0.000"
               + f"|FE:{Z3}>\r\n".encode()),)),
    Exchange("$13=1 reports in inches", steps=(
        Send(b"G0X25.4\n"), Wait(1.0), Send(b"$13=1\n"), Send(b"?"),
        Expect(OK + OK + b"<Idle|MPos:1.0000,0.0000,0.0000|Bf:15,128|FS:0.0,0"
               b"|WCO:0.0000,0.0000,0.0000|FE:0.0000,0.0000,0.0000>\r\n"),)),

    # ---- status reports
    Exchange("status reports: WCO in the first after reset, Ov in the second, then neither",
             steps=(
        Send(b"\x18"), Expect(BANNER),
        Send(b"?"), Expect(report("Idle", extra=WCO0)),
        Send(b"?"), Expect(report("Idle", extra=OV100)),
        Send(b"?"), Expect(report("Idle")),)),
    Exchange("WCO comes again at once when the offset changes", steps=(
        Send(b"?"), Send(b"?"), Send(b"?"), Do("discard", _discard),
        Send(b"G92X0\n"), Send(b"?"), Send(b"?"),
        Expect(OK + report("Idle", extra=WCO0) + report("Idle")),
        Send(b"G0X2\n"), Wait(0.1), Send(b"G92X0\n"), Send(b"?"),
        Expect(OK + OK + report("Idle", "2.000,0.000,0.000",
                                extra="|WCO:2.000,0.000,0.000")),)),
    Exchange("real-time bytes are never echoed, counted or kept in the buffer", steps=(
        Send(b"G1X1?F6\x91000\n"), Wait(0.002),
        Expect(b"<Idle|MPos:0.000,0.000,0.000|Bf:15,124|FS:0,0" + WCO0.encode()
               + f"|FE:{Z3}>\r\n".encode() + OK),)),
    Exchange("Run with feed, Ln of the executing line, Bf planner blocks and RX bytes", steps=(
        Send(b"N7G1X10F600\nN8G1X20\n"), Send(b"G4P0.5\n"), Wait(0.5), Send(b"?"),
        Expect(OK + OK + b"<Run|MPos:5.000,0.000,0.000|Bf:12,128|Ln:7|FS:600,0" + WCO0.encode()
               + b"|FE:0.005,0.000,0.000>\r\n"),)),
    Exchange("Pn names the triggered limit switches", steps=(
        Do("press the X and Z limit switches", _press_x_and_z_limits),
        Send(b"?"), Expect(report("Idle", extra="|Pn:XZ" + WCO0)),)),
    Exchange("a two-axis machine reports two coordinates everywhere", homed=False,
             machine={"axes": ("X", "Y"), "homing": False}, steps=(
        Expect(BANNER),
        Send(b"?"),
        Expect(b"<Idle|MPos:0.000,0.000|Bf:15,128|FS:0,0|WCO:0.000,0.000|FE:0.000,0.000>\r\n"),
        Send(b"$#\n"),
        Expect(b"".join(f"[{name}:0.000,0.000]\r\n".encode() for name in
                        ("G54", "G55", "G56", "G57", "G58", "G59", "G28", "G30", "G92"))
               + b"[TLO:0.000]\r\n[PRB:0.000,0.000:0]\r\n" + OK),
        Send(b"$J=Z1F100\n"), Expect(b"error:20\r\n"),)),
    Exchange("a four-axis machine reports four coordinates and $103", homed=False,
             machine={"axes": ("X", "Y", "Z", "A"), "homing": False}, steps=(
        Expect(BANNER),
        Send(b"G0A10\n"), Wait(1.0), Send(b"?"),
        Expect(OK + b"<Idle|MPos:0.000,0.000,0.000,10.000|Bf:15,128|FS:0,0"
               b"|WCO:0.000,0.000,0.000,0.000|FE:0.000,0.000,0.000,0.000>\r\n"),)),

    # ---- alarm lock
    Exchange("alarm lock: G-code error:9 until $X; $X says Caution: Unlocked", homed=False,
             steps=(
        Expect(BANNER + UNLOCK),
        Send(b"G0X1\n"), Send(b"?"),
        Expect(b"error:9\r\n" + report("Alarm", extra=WCO0)),
        Send(b"$X\n"), Expect(b"[MSG:Caution: Unlocked]\r\n" + OK),
        Send(b"$X\n"), Expect(OK),
        Send(b"G0X1\n"), Expect(OK),)),
    Exchange("$H homes, ok when done, state Home meanwhile", homed=False, steps=(
        Expect(BANNER + UNLOCK),
        Send(b"$H\n"), Wait(0.1), Send(b"?"), Expect(report("Home", extra=WCO0)),
        Wait(0.25), Expect(OK), Send(b"?"), Expect(report("Idle", extra=OV100)),)),
    Exchange("$H with homing disabled is error:5", machine={"homing": False}, homed=False,
             steps=(Expect(BANNER), Send(b"$H\n"), Expect(b"error:5\r\n"))),
    Exchange("a failed homing: the fault, ALARM:9, then ok for the $H", homed=False, steps=(
        Do("make homing fail", _homing_fails),
        Send(b"$H\n"), Wait(0.4),
        Expect(BANNER + UNLOCK + b"[MSG:X axis: homing: the switch was not found within the "
               b"search distance]\r\nALARM:9\r\n" + OK),
        Send(b"G0X1\n"), Expect(b"error:9\r\n"),)),
    Exchange("a fault mid-program: the axis, fault and line, ALARM:1, and as a hard limit "
             "nothing read until a reset", steps=(
        Do("arm a following-error fault on line 3", _fault_on_line_3),
        Send(b"N1G1X1F600\nN2G1X2\nN3G1X3\nN4G1X4\n"), Wait(0.3),
        Expect(OK * 4 + b"[MSG:Y axis: following error 2.000 mm over 1.000 mm (program line "
               b"3)]\r\nALARM:1\r\n[MSG:Reset to continue]\r\n"),
        Send(b"G0X0\n$X\n"), Wait(0.1), Send(b"?"),
        Expect(report("Alarm", "2.000,0.000,0.000", bf="15,120", extra=WCO0)),
        Send(b"\x18"), Expect(BANNER + UNLOCK),
        Send(b"$X\n"), Expect(b"[MSG:Caution: Unlocked]\r\n" + OK),)),
    Exchange("a fault that is not a limit: ALARM:N and the lock, G-code error:9", steps=(
        Do("arm a probe-like fault (alarm 4) on line 2", _probe_fault_on_line_2),
        Send(b"N1G1X1F600\nN2G1X2\n"), Wait(0.2),
        Expect(OK * 2 + b"[MSG:probe: not in the expected state (program line 2)]\r\n"
               b"ALARM:4\r\n"),
        Send(b"G0X0\n"), Expect(b"error:9\r\n"),
        Send(b"$X\n"), Expect(b"[MSG:Caution: Unlocked]\r\n" + OK),)),

    # ---- soft reset
    Exchange("soft reset at rest: the banner only", steps=(
        Send(b"\x18"), Expect(BANNER),)),
    Exchange("soft reset in motion: ALARM:3, the banner, the unlock hint", steps=(
        Send(b"G1X10F600\n"), Wait(0.2), Send(b"\x18"),
        Expect(OK + b"ALARM:3\r\n" + BANNER + UNLOCK),
        Send(b"?"), Expect(report("Alarm", "2.000,0.000,0.000", extra=WCO0)),)),
    Exchange("soft reset in Hold:0 (at rest): the banner only", steps=(
        Send(b"G1X10F600\n"), Wait(0.2), Send(b"!"), Wait(0.1), Send(b"\x18"),
        Expect(OK + BANNER),)),
    Exchange("a sender connecting while the machine moves: ALARM:3, then the banner",
             steps=(
        Send(b"G1X10F600\n"), Wait(0.2), Do("a new connection", _connect),
        Expect(OK + b"ALARM:3\r\n" + BANNER + UNLOCK),)),
    Exchange("a start-up line the machine rejects is not stored", steps=(
        Send(b"$N0=G5\n"), Send(b"$N\n"),
        Expect(b"[MSG:G5 is not supported by the test machine]\r\nerror:20\r\n"
               b"$N0=\r\n$N1=\r\n" + OK),)),
    Exchange("soft reset drops the receive buffer and what waits", steps=(
        Send(b"G1X10F600\nG4P0\nG0X0\n"), Send(b"\x18"), Send(b"$X\n?"),
        Expect(OK + b"ALARM:3\r\n" + BANNER + UNLOCK
               + report("Alarm", extra=WCO0, bf="15,125")
               + b"[MSG:Caution: Unlocked]\r\n" + OK),)),

    # ---- hold, resume, overrides, door
    Exchange("feed hold: Hold:1 while stopping, Hold:0 at rest, ~ resumes", steps=(
        Send(b"G1X10F600\n"), Wait(0.2), Send(b"!"), Send(b"?"), Wait(0.1), Send(b"?"),
        Send(b"~"), Wait(0.1), Send(b"?"),
        Expect(OK + report("Hold:1", "2.000,0.000,0.000", bf="14,128", fs="600,0",
                           extra=WCO0, fe="0.005,0.000,0.000")
               + report("Hold:0", "2.500,0.000,0.000", bf="14,128", extra=OV100)
               + report("Run", "3.500,0.000,0.000", bf="14,128", fs="600,0",
                        fe="0.005,0.000,0.000")),)),
    Exchange("feed overrides: +10, +1, -1, -10, reset; clamped at 200 and 10", steps=(
        Send(b"?"), Send(b"?"), Send(b"?"), Do("discard", _discard),
        Send(b"\x91"), Send(b"?"), Expect(report("Idle", extra="|Ov:110,100,100")),
        Send(b"\x93\x93\x94"), Send(b"?"), Expect(report("Idle", extra="|Ov:111,100,100")),
        Send(b"\x91" * 20), Send(b"?"), Expect(report("Idle", extra="|Ov:200,100,100")),
        Send(b"\x92" * 30), Send(b"?"), Expect(report("Idle", extra="|Ov:10,100,100")),
        Send(b"\x90"), Send(b"?"), Expect(report("Idle", extra=OV100)),)),
    Exchange("rapid overrides 50 and 25 and 100; spindle overrides counted", steps=(
        Send(b"?"), Send(b"?"), Send(b"?"), Do("discard", _discard),
        Send(b"\x96"), Send(b"?"), Expect(report("Idle", extra="|Ov:100,50,100")),
        Send(b"\x97\x9a\x9c"), Send(b"?"), Expect(report("Idle", extra="|Ov:100,25,111")),
        Send(b"\x95\x99\x9e\xa0\xa1\xff"), Send(b"?"), Expect(report("Idle", extra=OV100)),)),
    Exchange("safety door: Door:2 while stopping, Door:0 at rest, ~ resumes", steps=(
        Send(b"G1X10F600\n"), Wait(0.2), Send(b"\x84"), Send(b"?"), Wait(0.1), Send(b"?"),
        Send(b"~"), Wait(0.1), Send(b"?"),
        Expect(OK + report("Door:2", "2.000,0.000,0.000", bf="14,128", fs="600,0",
                           extra=WCO0, fe="0.005,0.000,0.000")
               + report("Door:0", "2.500,0.000,0.000", bf="14,128", extra=OV100)
               + report("Run", "3.500,0.000,0.000", bf="14,128", fs="600,0",
                        fe="0.005,0.000,0.000")),)),

    # ---- check mode
    Exchange("check mode: parsed and answered, nothing moves; leaving it resets", steps=(
        Send(b"$C\n"), Expect(b"[MSG:Enabled]\r\n" + OK),
        Send(b"G1X10F600\n"), Send(b"G5\n"), Wait(0.5), Send(b"?"),
        Expect(OK + b"[MSG:G5 is not supported by the test machine]\r\nerror:20\r\n"
               + report("Check", extra=WCO0)),
        Send(b"$C\n"), Expect(b"[MSG:Disabled]\r\n" + OK + BANNER),
        Send(b"?"), Expect(report("Idle", extra=WCO0)),)),
    Exchange("check mode needs idle: error:8 in alarm", homed=False, steps=(
        Expect(BANNER + UNLOCK), Send(b"$C\n"), Expect(b"error:8\r\n"),)),

    # ---- jogging
    Exchange("jog: ok at once, Jog state, incremental from the last jog's end", steps=(
        Send(b"$J=G91X5F600\n"), Send(b"$J=G91X5F600\n"), Wait(0.2), Send(b"?"),
        Expect(OK + OK + report("Jog", "2.000,0.000,0.000", bf="13,128", fs="600,0",
                                extra=WCO0, fe="0.005,0.000,0.000")),
        Wait(2.0), Send(b"?"), Expect(report("Idle", "10.000,0.000,0.000", extra=OV100)),)),
    Exchange("jog with G20 moves inches, G53 machine coordinates", steps=(
        Send(b"G92X0\n"), Send(b"$J=G20X1F60\n"), Wait(1.1), Send(b"$J=G53X0F6000\n"),
        Wait(0.5), Send(b"?"),
        Expect(OK + OK + OK + report("Idle", extra=WCO0)),)),
    Exchange("jog errors: no F 22, G1 16, S 36, no axis 26, M 16, no = 3, repeated 25",
             steps=(
        Send(b"$J=X5\n"), Send(b"$J=G1X5F100\n"), Send(b"$J=X5F100S1\n"), Send(b"$J=F100\n"),
        Send(b"$J=M3X1F100\n"), Send(b"$JX5F100\n"), Send(b"$J=X1X2F100\n"),
        Send(b"$J=G20G21X1F100\n"), Send(b"$J=X1F-5\n"),
        Expect(b"error:22\r\nerror:16\r\nerror:36\r\nerror:26\r\nerror:16\r\nerror:3\r\n"
               b"error:25\r\nerror:21\r\nerror:4\r\n"),)),
    Exchange("jog beyond the travel is error:15, nothing moves", steps=(
        Send(b"$J=X400F600\n"),
        Expect(b"[MSG:jog target beyond the travel]\r\nerror:15\r\n"),)),
    Exchange("jog cancel: stops, drops queued jogs, back to Idle", steps=(
        Send(b"$J=G91X5F600\n$J=G91X5F600\n"), Wait(0.2), Send(b"\x85"), Wait(0.01),
        Send(b"?"),
        Expect(OK + OK + report("Idle", "2.000,0.000,0.000", extra=WCO0)),)),
    Exchange("G-code while jogging is error:9; $J in alarm is error:8", homed=False, steps=(
        Send(b"$J=X1F100\n"), Send(b"$X\n"), Send(b"$J=X5F600\n"), Send(b"G0X0\n"),
        Expect(BANNER + UNLOCK + b"error:8\r\n[MSG:Caution: Unlocked]\r\n" + OK + OK
               + b"error:9\r\n"),)),
    Exchange("feed hold while jogging cancels the jog", steps=(
        Send(b"$J=G91X5F600\n"), Wait(0.2), Send(b"!"), Wait(0.01), Send(b"?"),
        Expect(OK + report("Idle", "2.000,0.000,0.000", extra=WCO0)),)),

    # ---- synchronisation and program flow
    Exchange("G4: its ok only once the motion before it has finished", steps=(
        Send(b"G1X10F600\nG4P0.01\n"), Wait(0.9), Expect(OK),
        Wait(0.2), Expect(OK),)),
    Exchange("M2: Pgm End once the motion is done, then ok", steps=(
        Send(b"G1X1F600\nM2\n"), Wait(0.05), Expect(OK),
        Wait(0.1), Expect(b"[MSG:Pgm End]\r\n" + OK),)),
    Exchange("M0 pauses after the motion before it; ~ goes on", steps=(
        Send(b"G1X1F600\nM0\nG1X2\n"), Wait(0.2), Send(b"?"),
        Expect(OK + OK + OK + report("Hold:0", "1.000,0.000,0.000", bf="14,128",
                                     extra=WCO0)),
        Send(b"~"), Wait(0.2), Send(b"?"),
        Expect(report("Idle", "2.000,0.000,0.000", extra=OV100)),)),
    Exchange("$$ and $# while running are error:8; $G is answered", steps=(
        Send(b"G1X10F600\n"), Send(b"$$\n"), Send(b"$#\n"), Send(b"$G\n"),
        Expect(OK + b"error:8\r\nerror:8\r\n[GC:G1 G54 G17 G21 G90 G94 M5 M9 T0 F600 S0]\r\n"
               + OK),)),
    Exchange("$SLP: ok, Sleeping, nothing read until a reset, which leaves alarm", steps=(
        Send(b"$SLP\n"), Send(b"G0X1\n"), Wait(0.05), Send(b"?"),
        Expect(OK + b"[MSG:Sleeping]\r\n"
               + report("Sleep", bf="15,123", extra=WCO0)),
        Send(b"\x18"), Expect(BANNER + UNLOCK),)),

    # ---- the receive buffer
    Exchange("a line over 79 characters is error:11; 79 are fine", steps=(
        Send(b"G1X1F600" + b"0" * 72 + b"\n"), Send(b"G4P0" + b"0" * 75 + b"\n"), Wait(0.01),
        Expect(b"error:11\r\n" + OK),)),
    Exchange("bytes past the 128-byte buffer are dropped, as grbl drops them", steps=(
        Send(b"G1X100F600\n" + b"G1X1\n" * 30),
        Do("161 bytes sent: 128 kept, 33 dropped", _dropped_33),
        Expect(OK * 15),
        Send(b"?"), Expect(report("Run", bf="0,86", extra=WCO0)),)),
)
