/*
 * The layout of the file the runner's libtracetools interposer (roscb.c, built as runner/run/_roscb*.so and
 * preloaded into `command:` programs) shares with the runner (runner/run/roscb.py), declared once: each record is
 * a list of fields (an X-macro, as records.h's) that gives both the C struct and, through records.c, the table of
 * field names, offsets and struct formats `_probe.records()` exports, from which Python reads every field by name.
 * No Python and no hook here: roscb.c and records.c both include it.
 *
 * File layout (little endian, fixed-width fields, no pointer-sized ones), version ROSCB_VERSION:
 *   file header, ROSCB_FILE_HEADER bytes (struct roscb_file), written by the runner before the program starts:
 *     magic "RROSCB01", the version, every size below (the library refuses a file whose sizes are not its own),
 *     then the claim counters the processes and threads bump
 *   max_procs process blocks of ROSCB_PROC_BYTES: a ROSCB_PROC_HEADER header (struct roscb_proc), then the
 *     process's string arena (names, topics, symbols, NUL-terminated, bump-allocated)
 *   max_threads thread slots of ROSCB_SLOT_HEADER + capacity * ROSCB_RECORD bytes: a header (struct roscb_slot),
 *     then a ring of records, record n at n % capacity; the thread alone writes it and never waits: the runner
 *     finds what it missed from count - capacity
 *   a record is one of struct roscb_callback, roscb_publish, roscb_meta, told apart by its first field, `type`
 * The runner makes the file sparse: only the blocks and slots processes and threads claim take memory, backed as
 * they are claimed (where /dev/shm has no room for one, it is refused: a write to a page tmpfs cannot back is a SIGBUS).
 */
#ifndef RUNNER_ROSCB_H
#define RUNNER_ROSCB_H

#include <stddef.h>
#include <stdint.h>

#define ROSCB_MAGIC 0x31304243534f5252ULL /* "RROSCB01" read as a little-endian u64 */
#define ROSCB_VERSION 1
#define ROSCB_FILE_HEADER 4096
#define ROSCB_PROC_HEADER 512
#define ROSCB_PROC_BYTES 65536 /* a process block: its header, then its string arena */
#define ROSCB_ARENA (ROSCB_PROC_BYTES - ROSCB_PROC_HEADER)
#define ROSCB_SLOT_HEADER 128
#define ROSCB_RECORD 96
#define ROSCB_STRING_MAX 1024 /* a string longer is cut here (and its record flagged truncated) */
#define ROSCB_STACK 8         /* callbacks open at once on one thread (nesting); deeper ones are counted, not kept */

enum roscb_type { ROSCB_CALLBACK = 1, ROSCB_PUBLISH = 2 }; /* meta records: 16 and up, runner/run/roscbdata.py MetaKind */

#define ROSCB_META_KINDS(X)                                                                                               \
    X(NODE, 16)                                                                                                           \
    X(PUB, 17)                                                                                                            \
    X(SUB, 18)                                                                                                            \
    X(SUBOBJ, 19)                                                                                                         \
    X(SUBCB, 20)                                                                                                          \
    X(SRV, 21)                                                                                                            \
    X(SRVCB, 22)                                                                                                          \
    X(TIMER, 23)                                                                                                          \
    X(TIMERCB, 24)                                                                                                        \
    X(TIMERNODE, 25)                                                                                                      \
    X(SYM, 26)
#define ROSCB_META_ENUM(name, code) ROSCB_META_##name = code,
enum roscb_meta_kind { ROSCB_META_KINDS(ROSCB_META_ENUM) };
#undef ROSCB_META_ENUM

/* A callback record's flags. */
#define ROSCB_CB_INTRA 1u        /* callback_start said is_intra_process */
#define ROSCB_CB_TAKE 2u         /* a take came before it on its thread: src_ts, age, take_handle are set */
#define ROSCB_CB_UNTERMINATED 4u /* its end never came: an outer callback's end or the thread's exit closed it */
#define ROSCB_CB_RELEASE 8u      /* release_ns is the timer's exact release */
/* A publish record's flags. */
#define ROSCB_PUB_EXACT 1u    /* src_ts is the middleware's own timestamp (3-argument rmw_publish, Jazzy and later) */
#define ROSCB_PUB_RCL 2u      /* handle is the rcl publisher of the rcl_publish before it (1-argument rmw_publish) */
/* A meta record's flags. */
#define ROSCB_META_TRUNCATED 1u /* a string was cut, or the arena had no room (then it is empty) */

/* A process block's flags: runner/run/roscb.py names them as roscbdata.ProcessFlag. */
#define ROSCB_P_TRACETOOLS 1u  /* dlsym(RTLD_NEXT) found the real ros_trace_callback_start */
#define ROSCB_P_ENABLED 2u     /* and ros_trace_enabled_callback_start (Iron and later) */
#define ROSCB_P_PUBLISH3 4u    /* rmw_publish takes (publisher, message, timestamp) (Jazzy and later) */
#define ROSCB_P_SHADOWED 8u    /* another object defines ros_trace_callback_start ahead of this library */
#define ROSCB_P_FORKED 16u     /* forked from a process that had reached a hook */

#define ROSCB_FILE_FIELDS(F, A)                                                                                           \
    F(uint64_t, magic)                                                                                                    \
    F(uint32_t, version)                                                                                                  \
    F(uint32_t, header_size)                                                                                              \
    F(uint32_t, max_procs)                                                                                                \
    F(uint32_t, max_threads)                                                                                              \
    F(uint32_t, capacity)       /* records per thread's ring */                                                          \
    F(uint32_t, record_size)                                                                                              \
    F(uint32_t, proc_size)                                                                                                \
    F(uint32_t, slot_size)      /* the slot header and its ring */                                                       \
    F(uint32_t, next_proc)      /* process blocks claimed (may pass max_procs: those were refused) */                    \
    F(uint32_t, next_thread)    /* thread slots claimed, likewise */                                                     \
    F(uint64_t, procs_refused)                                                                                            \
    F(uint64_t, threads_refused)

#define ROSCB_PROC_FIELDS(F, A)                                                                                           \
    F(uint32_t, state)          /* 0 free, 1 claimed (its fields written) */                                             \
    F(int32_t, pid)                                                                                                       \
    F(int32_t, ppid)                                                                                                      \
    F(uint32_t, flags)                                                                                                    \
    F(int64_t, first_hook_ns)                                                                                             \
    F(uint64_t, arena_used)     /* bytes of the arena handed out (may pass its size: then strings were dropped) */       \
    F(uint64_t, strings_dropped)                                                                                          \
    A(uint8_t, exe, 64)         /* the tail of /proc/self/exe, NUL-terminated */                                         \
    A(uint8_t, shadowed_by, 128) /* the object that defines ros_trace_callback_start ahead of this library */

#define ROSCB_SLOT_FIELDS(F, A)                                                                                           \
    F(uint32_t, state)          /* 0 free, 1 live, 2 exited */                                                           \
    F(int32_t, tid)                                                                                                       \
    F(int32_t, pid)                                                                                                       \
    F(uint32_t, proc)           /* its process block */                                                                  \
    A(uint8_t, comm, 16)                                                                                                  \
    F(uint64_t, count)          /* records written, all told; stored after each record (release) */                     \
    F(uint64_t, lost_other)     /* records not written: callback stack too deep, an end with no start */                 \
    F(uint64_t, open_cb)        /* the innermost callback running now; 0: none */                                        \
    F(int64_t, open_since_ns)                                                                                             \
    F(uint32_t, open_depth)     /* callbacks open now */

#define ROSCB_CALLBACK_FIELDS(F, A)                                                                                       \
    F(uint16_t, type)                                                                                                     \
    F(uint8_t, flags)                                                                                                     \
    F(uint8_t, depth)           /* callbacks of this thread it ran inside */                                              \
    F(int16_t, cpu_start)                                                                                                 \
    F(int16_t, cpu_end)                                                                                                   \
    F(uint64_t, cb)             /* the callback handle rclcpp passed */                                                   \
    F(int64_t, start_ns)        /* CLOCK_MONOTONIC */                                                                     \
    F(int64_t, end_ns)                                                                                                    \
    F(int64_t, release_ns)      /* 0: unknown */                                                                          \
    F(int64_t, wake_ns)         /* the executor's wake-up before it on this thread; 0: unknown */                        \
    F(int64_t, src_ts)          /* the taken message's source timestamp (CLOCK_REALTIME); 0: none */                     \
    F(int64_t, age_ns)          /* CLOCK_REALTIME at the start minus src_ts */                                           \
    F(uint64_t, take_handle)    /* the rmw subscription of that take */                                                   \
    F(uint32_t, nivcsw)         /* getrusage(RUSAGE_THREAD) deltas over the callback */                                  \
    F(uint32_t, nvcsw)                                                                                                    \
    F(uint32_t, minflt)                                                                                                   \
    F(uint32_t, majflt)                                                                                                   \
    F(uint32_t, seq)            /* per thread, from 0, in start order */                                                  \
    F(uint32_t, cpu_us)         /* user + system time of the thread during it (getrusage's resolution) */

#define ROSCB_PUBLISH_FIELDS(F, A)                                                                                        \
    F(uint16_t, type)                                                                                                     \
    F(uint8_t, flags)                                                                                                     \
    F(uint8_t, unused)                                                                                                    \
    F(int32_t, enclosing_seq)   /* the seq of the callback running when it published; -1: none */                        \
    F(uint64_t, handle)                                                                                                   \
    F(int64_t, t_ns)            /* CLOCK_MONOTONIC */                                                                     \
    F(int64_t, src_ts)          /* CLOCK_REALTIME: the middleware's, or the hook's own clock */                          \
    F(uint64_t, enclosing_cb)

#define ROSCB_META_FIELDS(F, A)                                                                                           \
    F(uint16_t, type)                                                                                                     \
    F(uint8_t, flags)                                                                                                     \
    F(uint8_t, unused)                                                                                                    \
    F(uint32_t, clock)          /* TIMER: the rcl clock type (0: unknown) */                                             \
    F(uint64_t, a)                                                                                                        \
    F(uint64_t, b)                                                                                                        \
    F(uint64_t, c)                                                                                                        \
    F(int64_t, d)                                                                                                         \
    F(int64_t, t_ns)                                                                                                      \
    F(int64_t, e)                                                                                                         \
    F(uint32_t, s1_off)         /* in the process's arena */                                                             \
    F(uint32_t, s1_len)                                                                                                   \
    F(uint32_t, s2_off)                                                                                                   \
    F(uint32_t, s2_len)

#define ROSCB_SCALAR(T, name) T name;
#define ROSCB_ARRAY(T, name, n) T name[n];

struct roscb_file {
    ROSCB_FILE_FIELDS(ROSCB_SCALAR, ROSCB_ARRAY)
    uint8_t reserved[ROSCB_FILE_HEADER - 64];
};
struct roscb_proc {
    ROSCB_PROC_FIELDS(ROSCB_SCALAR, ROSCB_ARRAY)
    uint8_t reserved[ROSCB_PROC_HEADER - 232];
};
struct roscb_slot {
    ROSCB_SLOT_FIELDS(ROSCB_SCALAR, ROSCB_ARRAY)
    uint8_t reserved[ROSCB_SLOT_HEADER - 68];
};
struct roscb_callback {
    ROSCB_CALLBACK_FIELDS(ROSCB_SCALAR, ROSCB_ARRAY)
};
struct roscb_publish {
    ROSCB_PUBLISH_FIELDS(ROSCB_SCALAR, ROSCB_ARRAY)
    uint8_t reserved[ROSCB_RECORD - 40];
};
struct roscb_meta {
    ROSCB_META_FIELDS(ROSCB_SCALAR, ROSCB_ARRAY)
    uint8_t reserved[ROSCB_RECORD - 72];
};

_Static_assert(offsetof(struct roscb_file, reserved) == 64 && sizeof(struct roscb_file) == ROSCB_FILE_HEADER, "roscb file header");
_Static_assert(offsetof(struct roscb_proc, reserved) == 232 && sizeof(struct roscb_proc) == ROSCB_PROC_HEADER, "roscb process header");
_Static_assert(offsetof(struct roscb_slot, reserved) == 68 && sizeof(struct roscb_slot) == ROSCB_SLOT_HEADER, "roscb slot header");
_Static_assert(sizeof(struct roscb_callback) == ROSCB_RECORD, "roscb callback record");
_Static_assert(sizeof(struct roscb_publish) == ROSCB_RECORD, "roscb publish record");
_Static_assert(sizeof(struct roscb_meta) == ROSCB_RECORD, "roscb meta record");
_Static_assert(offsetof(struct roscb_callback, cb) == 8 && offsetof(struct roscb_callback, cpu_us) == 92, "callback layout");
_Static_assert(offsetof(struct roscb_publish, handle) == 8 && offsetof(struct roscb_meta, a) == 8, "record layout");
_Static_assert(offsetof(struct roscb_slot, count) == 32 && offsetof(struct roscb_proc, exe) == 40, "header layout");

#endif
