/*
 * The table of the native records (records.h): each field's name, offset, size and struct format, as the
 * compiler laid the structs out.  _probe.c exports it as `_probe.records()`; runner/run/records.py reads it.
 */
#include "records.h"
#include "roscb.h" /* the interposer's file (roscb.c is a library of its own): its records are read the same way */

/* The struct format of a field's type: the one place a C type meets its Python struct code. */
#define RECORD_CODE(T) \
    _Generic((T)0, int16_t: "h", uint16_t: "H", int32_t: "i", uint32_t: "I", int64_t: "q", uint64_t: "Q", double: "d", uint8_t: "B")
#define ROW_ARRAY(T, name, n) {#name, offsetof(RECORD, name), sizeof(((RECORD *)0)->name), RECORD_CODE(T), n},
#define ROW_SCALAR(T, name) ROW_ARRAY(T, name, 1)

#define RECORD struct slot_header
static const struct record_field slot_header_fields[] = {SLOT_HEADER_FIELDS(ROW_SCALAR, ROW_ARRAY)};
#undef RECORD
#define RECORD struct sample
static const struct record_field sample_fields[] = {SAMPLE_FIELDS(ROW_SCALAR, ROW_ARRAY)};
#undef RECORD
#define RECORD struct lock_wait
static const struct record_field lock_wait_fields[] = {LOCK_WAIT_FIELDS(ROW_SCALAR, ROW_ARRAY)};
#undef RECORD
#define RECORD struct event_stats
static const struct record_field event_stats_fields[] = {EVENT_STATS_FIELDS(ROW_SCALAR, ROW_ARRAY)};
#undef RECORD
#define RECORD struct phase_stats
static const struct record_field phase_stats_fields[] = {PHASE_STATS_FIELDS(ROW_SCALAR, ROW_ARRAY)};
#undef RECORD

#define RECORD struct roscb_file
static const struct record_field roscb_file_fields[] = {ROSCB_FILE_FIELDS(ROW_SCALAR, ROW_ARRAY)};
#undef RECORD
#define RECORD struct roscb_proc
static const struct record_field roscb_proc_fields[] = {ROSCB_PROC_FIELDS(ROW_SCALAR, ROW_ARRAY)};
#undef RECORD
#define RECORD struct roscb_slot
static const struct record_field roscb_slot_fields[] = {ROSCB_SLOT_FIELDS(ROW_SCALAR, ROW_ARRAY)};
#undef RECORD
#define RECORD struct roscb_callback
static const struct record_field roscb_callback_fields[] = {ROSCB_CALLBACK_FIELDS(ROW_SCALAR, ROW_ARRAY)};
#undef RECORD
#define RECORD struct roscb_publish
static const struct record_field roscb_publish_fields[] = {ROSCB_PUBLISH_FIELDS(ROW_SCALAR, ROW_ARRAY)};
#undef RECORD
#define RECORD struct roscb_meta
static const struct record_field roscb_meta_fields[] = {ROSCB_META_FIELDS(ROW_SCALAR, ROW_ARRAY)};
#undef RECORD

#define TABLE(S) {#S, sizeof(struct S), S##_fields, (int)(sizeof(S##_fields) / sizeof(S##_fields[0]))}
const struct record_table native_records[] = {TABLE(slot_header), TABLE(sample), TABLE(lock_wait), TABLE(event_stats), TABLE(phase_stats),
                                             TABLE(roscb_file),  TABLE(roscb_proc),  TABLE(roscb_slot), TABLE(roscb_callback),
                                             TABLE(roscb_publish), TABLE(roscb_meta)};
const int native_nrecords = (int)(sizeof(native_records) / sizeof(native_records[0]));
