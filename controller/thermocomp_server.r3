;; thermocomp_server.r3 -- the thermocomp fast path on the CRS C500C (RAPL-3).
;;
;; Serves the binary protocol of controller/PROTOCOL.md on the second serial port: one frame
;; per compensation step (goal k + offset, move, wait, answer the actual pose) instead of five
;; console commands and a `w2` table (docs/reference/c500c-console.md "The fast path"). The absolute location command
;; of the thesis (6.4.4): every target is the taught goal plus an offset, so an error in one
;; step is corrected by the next. HOLD halt()s a motion in progress; so does host silence.
;;
;; NOBODY HAS COMPILED THIS FILE. No RAPL-3 manual is public; every built-in below is one that
;; public RAPL-3 code uses, and each is cited:
;;   [rcs]  PetteriAimonen/crs-c500c-utils simple_message/robot_control_server.r3
;;   [sf]   same repository, simple_message/serial_framing.r3
;;   [ros]  same repository, rosserial_cros/cros_app/rosserial.r3
;;   [main] same repository, rosserial_cros/cros_app/main.r3
;;   [st]   same repository, trajectory/simple_test.r3
;;   [grs]  same repository, tests/getrotspd.r3
;;   [lang] same repository, syntax_hilight/rapl-3.lang: the NAME is a RAPL-3 built-in, its
;;          signature is not shown anywhere -> marked UNCONFIRMED where used.
;; Compile on the controller: r3c -Wall thermocomp_server.r3 (simple_message/Makefile), run
;; ./thermocomp_server. See docs/how-to/fast-path.md.

;; --- constants (controller/PROTOCOL.md) ------------------------------------------------------

const SILENCE_MS = 1000        ;; PROTOCOL.md "Silence": halt and hold after this long unheard
const POLL_MS = 1              ;; msleep between polls; the CROS tick is 5 ms (doc/Notes.rst)
const MAX_BODY = 32
const MAX_GOALS = 16           ;; PROTOCOL.md "Goals": taught goals, indices 0 .. MAX_GOALS - 1
const MOVE_LEN = 25            ;; offset (6 x int32) + mode; + 1 goal byte for goal k > 0
;; Receive fifo size: a preprocessor define, as rosserial.r3 sizes its 512-byte fifo [ros].
.define RX_SIZE 512

const T_HEARTBEAT = 1
const T_TEACH = 2
const T_MOVE_GOAL = 3
const T_MOVE_REL = 4
const T_READ = 5
const T_HOLD = 6
const T_RELEASE = 7

const S_OK = 0
const S_HALTED = 44            ;; catalogue 044 `Halt() command invoked` (docs/reference/c500c-console.md)
const S_NO_GOAL = 1001
const S_HELD = 1002
const S_BAD = 1003
const S_NO_CONTROL = 1004
const S_BUSY = 1005

const F_GOAL = 1
const F_HELD = 2
const F_MOVING = 4
const F_CONTROL = 8
const F_SILENCE = 16

;; A location seen as words. getrotspd.r3 overlays a ploc with int[9] (flags + 8 axes) [grs];
;; trajectory/simple_test.r3 writes a cloc literal of 9 values [st]. ASSUMED: a cloc is one
;; flags word then 8 floats X, Y, Z, Z-rot, Y-rot, X-rot, e1, e2 (mm, degrees). UNCONFIRMED:
;; a typedef of a union (typedef ... struct [rcs] and an inline union [grs] are confirmed).
typedef wloc_t union
    cloc c
    int[9] w
    float[9] f
end union

;; --- state (module-level variables, as rosserial.r3's g_* [ros]) -----------------------------

int g_fd = -1
string[RX_SIZE] g_rx = ""
string[64] g_tx = ""
;; Arrays of a struct/union type: UNCONFIRMED (arrays of int [main] and of char are confirmed).
wloc_t[MAX_GOALS] g_goal
wloc_t g_cur
int[MAX_GOALS] g_goal_taught   ;; 1 once goal k is taught; module-level ints start at 0 [ros]
int g_goals_taught = 0         ;; how many goals are taught (flags bit 0)
int g_control = 0
int g_held = 0
int g_silence = 0
int g_moving = 0
int g_halted = 0
int g_move_seq = 0
int g_move_type = 0
int[2] g_heard                 ;; mtime() of the last valid frame [main]
int g_heard_any = 0

;; --- arithmetic ------------------------------------------------------------------------------

;; XOR from + - * & only: `^` appears in no public RAPL-3 code; & | << >> do [sf].
func int xor(int a, int b)
    return a + b - 2 * (a & b)
end func

;; CRC-16/CCITT-FALSE, one byte (PROTOCOL.md "Frame").
func int crc_byte(int crc, int byte)
    int i
    crc = xor(crc, (byte & 255) << 8)
    for i = 1 to 8
        if (crc & 0x8000) != 0 then
            crc = xor((crc << 1) & 0xFFFF, 0x1021)
        else
            crc = (crc << 1) & 0xFFFF
        end if
    end for
    return crc
end func

func int crc_of(var string[] s, int first, int last)
    int i
    int crc = 0xFFFF
    for i = first to last
        crc = crc_byte(crc, str_chr_get(s, i))      ;; str_chr_get [sf][ros]
    end for
    return crc
end func

;; Little-endian int32 at s[i]; ASSUMED 32-bit two's-complement ints (the 486), so the top
;; byte's shift gives the sign.
func int get_i32(var string[] s, int i)
    return str_chr_get(s, i) | (str_chr_get(s, i + 1) << 8) | (str_chr_get(s, i + 2) << 16) | (str_chr_get(s, i + 3) << 24)
end func

sub put_i32(var string[] s, int i, int v)
    str_chr_set(s, i, v & 255)                      ;; str_chr_set [ros]
    str_chr_set(s, i + 1, (v >> 8) & 255)
    str_chr_set(s, i + 2, (v >> 16) & 255)
    str_chr_set(s, i + 3, (v >> 24) & 255)
end sub

;; Round to the nearest count; the <int>(x + 0.5) cast is robot_control_server.r3's [rcs].
func int counts(float x)
    if x < 0 then
        return -(<int>(-x * 10000.0 + 0.5))
    end if
    return <int>(x * 10000.0 + 0.5)
end func

;; Milliseconds since the last valid frame.
func int silent_ms()
    int[2] now
    mtime(&now)                                     ;; mtime(&int[2]) [main]; ms ASSUMED
    return now[0] - g_heard[0]
end func

;; --- replies ---------------------------------------------------------------------------------

func int flags()
    int f = 0
    if g_goals_taught != 0 then
        f |= F_GOAL
    end if
    if g_held != 0 then
        f |= F_HELD
    end if
    if g_moving != 0 then
        f |= F_MOVING
    end if
    if g_control != 0 then
        f |= F_CONTROL
    end if
    if g_silence != 0 then
        f |= F_SILENCE
    end if
    return f
end func

;; Frame a reply (35 bytes) with the actual pose now, and write it (PROTOCOL.md "Reply").
sub reply(int seq, int type, int status)
    wloc_t act
    int i, crc, len
    here(act.c)                                     ;; here(cloc) [st]
    str_len_set(g_tx, 35)                           ;; str_len_set [ros]
    str_chr_set(g_tx, 0, 0xA5)
    str_chr_set(g_tx, 1, 0x5A)
    str_chr_set(g_tx, 2, 27)
    str_chr_set(g_tx, 3, seq & 255)
    str_chr_set(g_tx, 4, (seq >> 8) & 255)
    str_chr_set(g_tx, 5, (type | 0x80) & 255)
    str_chr_set(g_tx, 6, status & 255)
    str_chr_set(g_tx, 7, (status >> 8) & 255)
    str_chr_set(g_tx, 8, flags())
    for i = 0 to 5
        put_i32(g_tx, 9 + 4 * i, counts(act.f[i + 1]))
    end for
    crc = crc_of(g_tx, 2, 32)
    str_chr_set(g_tx, 33, crc & 255)
    str_chr_set(g_tx, 34, (crc >> 8) & 255)
    ;; writes(fd, string, 0) returns the bytes written, possibly fewer on a non-blocking fd;
    ;; the rest is cut off the front with str_edit, as rosserial_readwrite() does [ros].
    while str_len(g_tx) > 0
        len = writes(g_fd, g_tx, 0)
        if len > 0 then
            str_edit(g_tx, "", 0, len)
        else
            msleep(POLL_MS)                         ;; msleep [ros]
        end if
    end while
end sub

;; --- motion ----------------------------------------------------------------------------------

;; halt() ends the motion in progress with error 044 (docs/reference/c500c-console.md). UNCONFIRMED signature:
;; `halt` is a name only [lang]; robot_control_server.r3 stops with robot_abort() [rcs].
sub hold(int silence)
    if g_moving != 0 then
        halt()                                      ;; UNCONFIRMED: halt() [lang]
        g_halted = 1
    end if
    g_held = 1
    if silence != 0 then
        g_silence = 1
    end if
end sub

;; MOVE_GOAL / MOVE_RELATIVE: cur = base (goal k or the actual pose) shifted by the offset's
;; six values (x, y, z mm; z-rot, y-rot, x-rot degrees) in world coordinates, then move; the
;; reply waits for the end of the motion (poll_move).
sub start_move(int seq, int type, int body, int goal)
    wloc_t offset
    int i, status
    if g_held != 0 then
        reply(seq, type, S_HELD)
        return
    elseif g_moving != 0 then
        reply(seq, type, S_BUSY)
        return
    elseif g_control == 0 then
        reply(seq, type, S_NO_CONTROL)
        return
    elseif type == T_MOVE_GOAL and g_goal_taught[goal] == 0 then
        reply(seq, type, S_NO_GOAL)
        return
    end if
    if type == T_MOVE_GOAL then
        for i = 0 to 8
            g_cur.w[i] = g_goal[goal].w[i]          ;; a word copy: no struct assignment seen
        end for
    else
        here(g_cur.c)                               ;; [st]
    end if
    memset(&offset, 0, sizeof(offset))              ;; memset, sizeof [rcs]
    for i = 0 to 5
        offset.f[i + 1] = get_i32(g_rx, body + 4 * i) / 10000.0    ;; int/float: UNCONFIRMED
    end for
    shift_w(g_cur.c, offset.c)                      ;; shift_w(cloc, cloc) [st]
    if str_chr_get(g_rx, body + 24) == 1 then
        status = moves(g_cur.c)                     ;; moves(cloc) [st]; its return: UNCONFIRMED
    else
        status = move(g_cur.c)                      ;; move(loc), `status < 0` on error [rcs]
    end if
    if status < 0 then
        ;; The catalogue number of a failed motion: err_get_code is a name only [lang].
        reply(seq, type, err_get_code(status))      ;; UNCONFIRMED: err_get_code(int)
        return
    end if
    g_moving = 1
    g_halted = 0
    g_move_seq = seq
    g_move_type = type
end sub

;; Called every poll: answer the move once the arm has stopped (robotisfinished() [grs]).
sub poll_move()
    ;; ASSUMED: after halt() the motion counts as finished.
    if g_moving != 0 and robotisfinished() then
        g_moving = 0
        if g_halted != 0 then
            reply(g_move_seq, g_move_type, S_HALTED)
        else
            reply(g_move_seq, g_move_type, S_OK)
        end if
    end if
end sub

;; --- requests --------------------------------------------------------------------------------

;; The goal index of a TEACH_GOAL (body: 0 or 1 byte) or a MOVE_GOAL (after the 25 bytes);
;; -1 when it is out of range (a bad request).
func int goal_of(int len, int bare)
    int goal = 0
    if len == bare + 1 then
        goal = str_chr_get(g_rx, 6 + bare)
    end if
    if goal >= MAX_GOALS then
        return -1
    end if
    return goal
end func

sub serve(int seq, int type, int len)
    int body = 6
    int goal = 0
    if type == T_MOVE_GOAL or type == T_MOVE_REL then
        if len == MOVE_LEN + 1 and type == T_MOVE_GOAL then
            goal = goal_of(len, MOVE_LEN)
        elseif len != MOVE_LEN then
            goal = -1
        end if
        if goal < 0 then
            reply(seq, type, S_BAD)
        else
            start_move(seq, type, body, goal)
        end if
        return
    end if
    if type == T_TEACH and len <= 1 then
        goal = goal_of(len, 0)
        if goal < 0 then
            reply(seq, type, S_BAD)
        elseif g_moving != 0 then
            reply(seq, type, S_BUSY)
        else
            here(g_goal[goal].c)                    ;; here(goal k) [st]
            if g_goal_taught[goal] == 0 then
                g_goal_taught[goal] = 1
                g_goals_taught = g_goals_taught + 1
            end if
            reply(seq, type, S_OK)
        end if
        return
    end if
    if len != 0 then
        reply(seq, type, S_BAD)
    elseif type == T_HEARTBEAT or type == T_READ then
        reply(seq, type, S_OK)
    elseif type == T_HOLD then
        hold(0)
        reply(seq, type, S_OK)
    elseif type == T_RELEASE then
        g_held = 0
        g_silence = 0
        reply(seq, type, S_OK)
    else
        reply(seq, type, S_BAD)
    end if
end sub

;; One frame off the front of g_rx if a whole one is there (PROTOCOL.md "Receiving"): resync on
;; garbage, on LEN > MAX_BODY and on a bad CRC (drop the sync only). Returns 1 if it consumed
;; anything, so the caller loops until 0.
func int take_frame()
    int n, len, total, crc
    n = str_len(g_rx)                               ;; str_len [ros]
    if n < 2 then
        return 0
    end if
    if str_chr_get(g_rx, 0) != 0xA5 or str_chr_get(g_rx, 1) != 0x5A then
        str_edit(g_rx, "", 0, 1)                    ;; str_edit(fifo, "", 0, n) [ros]
        return 1
    end if
    if n < 6 then
        return 0
    end if
    len = str_chr_get(g_rx, 2)
    if len > MAX_BODY then
        str_edit(g_rx, "", 0, 2)
        return 1
    end if
    total = 8 + len
    if n < total then
        return 0
    end if
    crc = str_chr_get(g_rx, 6 + len) | (str_chr_get(g_rx, 7 + len) << 8)
    if crc != crc_of(g_rx, 2, 5 + len) then
        str_edit(g_rx, "", 0, 2)
        return 1
    end if
    mtime(&g_heard)
    g_heard_any = 1
    serve(str_chr_get(g_rx, 3) | (str_chr_get(g_rx, 4) << 8), str_chr_get(g_rx, 5), len)
    str_edit(g_rx, "", 0, total)
    return 1
end func

;; --- main ------------------------------------------------------------------------------------

main
    sio_ioctl_conf conf

    ;; The second port, binary, non-blocking: open flags as robot_control_server.r3 [rcs]
    ;; (O_RDWR | O_BINARY) and rosserial main.r3 [main] (O_NONBLOCK); together UNCONFIRMED.
    open(g_fd, "/dev/sio1", O_RDWR | O_BINARY | O_NONBLOCK, 0)
    ;; 115200 8N1 with every flow control off: the ioctl and fields of [rcs], values changed.
    ioctl(g_fd, IOCTL_GETC, &conf)
    conf.baud = 115200
    conf.OutxCtsFlow = 0
    conf.OutxDsrFlow = 0
    conf.DsrSensitivity = 0
    conf.OutX = 0
    conf.InX = 0
    ioctl(g_fd, IOCTL_PUTC, &conf)

    ;; Point of control once, before serving (docs/reference/c500c-console.md: the library prints "Press the
    ;; PAUSE/CONTINUE button..." and waits for the operator) [rcs]: ctl_get() < 0 on failure.
    if ctl_get() < 0 then
        printf("thermocomp_server: no point of control; motion will be refused\n")
    else
        g_control = 1
    end if
    online(ON)                                      ;; straight-line moves need it [rcs][st]
    printf("thermocomp_server: serving /dev/sio1 at 115200\n")

    while 1 == 1
        readsa(g_fd, g_rx, RX_SIZE - str_len(g_rx))  ;; append what arrived [ros]
        while take_frame()
        end while
        poll_move()
        if g_heard_any != 0 and g_held == 0 and silent_ms() > SILENCE_MS then
            printf("thermocomp_server: host silent: halting\n")
            hold(1)
        end if
        msleep(POLL_MS)
    end while
end main
