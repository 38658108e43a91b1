/*
 * runner.run._probe: the native core of the runner, its Python side.
 *
 * Everything measured runs in threads that never touch the Python interpreter:
 * their code is in interp.c, which does not include Python.h.  This file holds
 * the bindings: the Group object (a worker's threads around one shared buffer;
 * see records.h for its layout), the watchdog, and the module's functions.
 *
 * A Group owns the threads of one worker process.  Threads are created with
 * pthread_create from the calling thread, so the kernel's own inheritance
 * rules decide what they start with; a thread with settings of its own applies
 * them to itself.  Each thread records into its slot of a shared, file-backed
 * buffer that the runner reads while the run goes on and after
 * it ends, even when the worker dies.  The loop allocates nothing.
 */
#define _GNU_SOURCE
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <errno.h>
#include <fcntl.h>
#include <malloc.h>
#include <pthread.h>
#include <sched.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdint.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/prctl.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include "interp.h"
#include "roscb.h"

/* Fill a settings struct from Python values; returns -1 with an exception set.
 * `extra` is None or (dl_runtime, dl_deadline, dl_period, util_min, util_max), -1 for a uclamp left as is. */
static int parse_settings(PyObject *policy, PyObject *priority, PyObject *nice, PyObject *cpus, PyObject *extra, struct settings *out) {
    memset(out, 0, sizeof(*out));
    out->policy = -1;
    out->util_min = out->util_max = -1;
    if (extra && extra != Py_None) {
        long long rt, dl, per;
        if (!PyArg_ParseTuple(extra, "LLLii", &rt, &dl, &per, &out->util_min, &out->util_max)) return -1;
        out->dl_runtime = rt;
        out->dl_deadline = dl;
        out->dl_period = per;
    }
    if (policy != Py_None) {
        out->policy = (int)PyLong_AsLong(policy);
        out->priority = priority == Py_None ? 0 : (int)PyLong_AsLong(priority);
    }
    if (nice != Py_None) {
        out->has_nice = 1;
        out->nice = (int)PyLong_AsLong(nice);
    }
    if (PyErr_Occurred()) return -1;
    if (cpus != Py_None) {
        PyObject *seq = PySequence_Fast(cpus, "cpus must be a sequence of ints");
        if (!seq) return -1;
        Py_ssize_t n = PySequence_Fast_GET_SIZE(seq);
        if (n > 1024) n = 1024;
        for (Py_ssize_t i = 0; i < n; i++) {
            out->cpus[i] = (int)PyLong_AsLong(PySequence_Fast_GET_ITEM(seq, i));
        }
        out->ncpus = (int)n;
        Py_DECREF(seq);
        if (PyErr_Occurred()) return -1;
    }
    return 0;
}

/* ------------------------------------------------------------ Group object */

typedef struct {
    PyObject_HEAD
    struct group g;
    Py_buffer view;
    int has_view;
    Py_buffer res_view;
    int has_res;
} GroupObject;

static void Group_dealloc(GroupObject *self) {
    if (self->g.slots) {
        gate_cancel(self->g.base); /* never opened: parked threads leave */
        Py_BEGIN_ALLOW_THREADS
        join_all(&self->g);
        Py_END_ALLOW_THREADS
        for (uint32_t i = 0; i < self->g.nslots; i++) {
            program_release(self->g.slots[i].pstate);
            PyMem_Free(self->g.slots[i].prog);
        }
        PyMem_Free(self->g.slots);
    }
    if (self->has_view) PyBuffer_Release(&self->view);
    if (self->has_res) PyBuffer_Release(&self->res_view);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

static int Group_init(GroupObject *self, PyObject *args, PyObject *kwds) {
    static char *kwlist[] = {"buffer", "nthreads", "capacity", "all_cpus", "histograms", "events", "phases", "resources", "locks", NULL};
    PyObject *buffer, *all_cpus, *resources = Py_None;
    unsigned int nthreads, capacity, nstats = 0, nphases = 0, locks = 0;
    int with_hist = 1;
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "OIIO|pIIOI", kwlist, &buffer, &nthreads, &capacity, &all_cpus, &with_hist, &nstats,
                                     &nphases, &resources, &locks))
        return -1;
    if (nstats > MAX_EVENTS + 1 || nphases > MAX_PHASES || locks > MAX_LOCK_SLOTS) {
        PyErr_Format(PyExc_ValueError, "at most %d events, %d phases and %d lock slots per thread", MAX_EVENTS, MAX_PHASES, MAX_LOCK_SLOTS);
        return -1;
    }
    if (PyObject_GetBuffer(buffer, &self->view, PyBUF_WRITABLE) != 0) return -1;
    self->has_view = 1;
    if (resources != Py_None) {
        if (PyObject_GetBuffer(resources, &self->res_view, PyBUF_WRITABLE) != 0) return -1;
        self->has_res = 1;
    }
    size_t sample_size = sizeof(struct sample) + locks * sizeof(struct lock_wait);
    size_t ring_bytes = (size_t)capacity * sample_size;
    size_t stat_bytes = (size_t)nstats * (EV_HDR + HIST_BUCKETS * sizeof(uint64_t)) + (size_t)nphases * PHASE_BYTES;
    size_t stride = SLOT_HEADER + (with_hist ? HIST_SETS * HIST_BUCKETS * sizeof(uint64_t) : 0) + ring_bytes + stat_bytes;
    Py_ssize_t need = FILE_HEADER + (Py_ssize_t)nthreads * (Py_ssize_t)stride;
    if (self->view.len < need) {
        PyErr_Format(PyExc_ValueError, "buffer holds %zd bytes, %zd needed", self->view.len, need);
        return -1;
    }
    struct group *g = &self->g;
    memset(g, 0, sizeof(*g));
    g->base = self->view.buf;
    g->size = self->view.len;
    g->nslots = nthreads;
    g->capacity = capacity;
    g->with_hist = with_hist;
    g->stride = stride;
    g->nstats = nstats;
    g->nphases = nphases;
    g->lock_slots = locks;
    g->sample_size = sample_size;
    g->res = self->has_res ? self->res_view.buf : NULL;
    g->nres = self->has_res ? self->res_view.len / RES_BYTES : 0;
    g->page_size = sysconf(_SC_PAGESIZE);
    CPU_ZERO(&g->all_cpus);
    PyObject *seq = PySequence_Fast(all_cpus, "all_cpus must be a sequence");
    if (!seq) return -1;
    for (Py_ssize_t i = 0; i < PySequence_Fast_GET_SIZE(seq); i++)
        CPU_SET((int)PyLong_AsLong(PySequence_Fast_GET_ITEM(seq, i)), &g->all_cpus);
    Py_DECREF(seq);
    g->slots = PyMem_Calloc(nthreads ? nthreads : 1, sizeof(struct slot));
    if (!g->slots) {
        PyErr_NoMemory();
        return -1;
    }
    memcpy(g->base, "RSMP0007", 8);
    uint32_t meta[6] = {7, nthreads, capacity, SLOT_HEADER, (uint32_t)sample_size, with_hist ? HIST_BUCKETS : 0};
    memcpy(g->base + 8, meta, sizeof(meta));
    uint64_t stride64 = g->stride;
    memcpy(g->base + 32, &stride64, sizeof(stride64));
    uint32_t meta2[2] = {nstats, nphases};
    memcpy(g->base + 40, meta2, sizeof(meta2));
    for (uint32_t i = 0; i < nthreads; i++) {
        struct slot *s = &g->slots[i];
        char *at = g->base + FILE_HEADER + (size_t)i * g->stride;
        s->group = g;
        s->index = (int)i;
        s->after = -1;
        s->hdr = (struct slot_header *)at;
        s->hist = with_hist ? (uint64_t *)(at + SLOT_HEADER) : NULL;
        s->ring = at + SLOT_HEADER + (with_hist ? HIST_SETS * HIST_BUCKETS * sizeof(uint64_t) : 0);
        s->capacity = capacity;
        s->evbase = s->ring + ring_bytes;
        s->phbase = s->evbase + (size_t)nstats * (EV_HDR + HIST_BUCKETS * sizeof(uint64_t));
        s->stride = g->stride;
        memset(s->hdr, 0, SLOT_HEADER);
        s->hdr->minflt_first = -1;
    }
    return 0;
}

/* Parse a program: (gid, delay_ns, loop, mem_bytes, phases, events); phases are
 * (loop, first, nevents, settings or None), settings (policy, priority, nice, cpus, extra),
 * events (type, res, res2, mode, arg).  Indexes are checked against the group's sizes. */
static struct program *parse_program(const struct group *g, PyObject *spec) {
    long long gid, delay, loop, mem;
    PyObject *phases, *events;
    if (!PyArg_ParseTuple(spec, "LLLLOO", &gid, &delay, &loop, &mem, &phases, &events)) return NULL;
    PyObject *ph = PySequence_Fast(phases, "phases must be a sequence");
    if (!ph) return NULL;
    PyObject *ev = PySequence_Fast(events, "events must be a sequence");
    if (!ev) {
        Py_DECREF(ph);
        return NULL;
    }
    struct program *p = PyMem_Calloc(1, sizeof(struct program));
    Py_ssize_t np = PySequence_Fast_GET_SIZE(ph), ne = PySequence_Fast_GET_SIZE(ev);
    if (!p) {
        PyErr_NoMemory();
        goto fail;
    }
    if (np < 1 || np > (Py_ssize_t)g->nphases || ne + 1 > (Py_ssize_t)g->nstats) {
        PyErr_Format(PyExc_ValueError, "program of %zd phases and %zd events does not fit the group (%u phases, %u event stats)", np, ne,
                     g->nphases, g->nstats);
        goto fail;
    }
    p->gid = (int32_t)gid;
    p->delay_ns = delay;
    p->loop = loop;
    p->mem_bytes = mem;
    p->nphases = (int)np;
    p->nevents = (int)ne;
    for (Py_ssize_t i = 0; i < ne; i++) {
        struct event *e = &p->events[i];
        long long arg;
        if (!PyArg_ParseTuple(PySequence_Fast_GET_ITEM(ev, i), "iiiiL", &e->type, &e->res, &e->res2, &e->mode, &arg)) goto fail;
        e->arg = arg;
        int known = e->type > EV_NONE && e->type < EV_COUNT;
        int needs = known && ev_needs_resource[e->type];
        if ((needs && (e->res < 0 || e->res >= g->nres)) || (e->type == EV_WAIT && (e->res2 < 0 || e->res2 >= g->nres)) ||
            (e->type == EV_LOCK && (e->res2 < -1 || e->res2 >= (int)g->lock_slots)) ||
            (e->type == EV_TIMER && e->arg <= 0) ||
            (e->type == EV_SPAWN && (e->res < 0 || e->arg < 1 || e->res + e->arg > (long long)g->nslots)) || !known ||
            (e->type == EV_IORUN && mem < 1)) {
            PyErr_Format(PyExc_ValueError, "event %zd (type %d) names resource %d of %zd or lock slot %d of %u, or has no period", i, e->type,
                         e->res, g->nres, e->res2, g->lock_slots);
            goto fail;
        }
        /* A timer's state is the first event naming the same timer: a named one by name, and the thread's
         * private timers as one (rt-app's `unique` timer: its grid advances by each event's own period). */
        e->key = (int)i;
        if (e->type == EV_TIMER) {
            for (Py_ssize_t k = 0; k < i; k++)
                if (p->events[k].type == EV_TIMER && p->events[k].res == e->res) {
                    e->key = (int)k;
                    break;
                }
        }
    }
    int timers = 0, suspends = 0;
    for (Py_ssize_t i = 0; i < ne; i++) {
        timers += p->events[i].type == EV_TIMER;
        suspends += p->events[i].type == EV_SUSPEND;
    }
    p->released = timers == 0 && suspends > 0;
    for (Py_ssize_t i = 0; i < np; i++) {
        struct phase *f = &p->phases[i];
        long long floop;
        PyObject *set;
        if (!PyArg_ParseTuple(PySequence_Fast_GET_ITEM(ph, i), "LiiO", &floop, &f->first, &f->nevents, &set)) goto fail;
        f->loop = floop;
        if (f->first < 0 || f->nevents < 0 || f->first + f->nevents > p->nevents) {
            PyErr_Format(PyExc_ValueError, "phase %zd has events outside the program", i);
            goto fail;
        }
        if (set != Py_None) {
            PyObject *policy, *priority, *nice, *cpus, *extra;
            if (!PyArg_ParseTuple(set, "OOOOO", &policy, &priority, &nice, &cpus, &extra)) goto fail;
            if (parse_settings(policy, priority, nice, cpus, extra, &f->set)) goto fail;
            f->has_settings = 1;
        }
    }
    Py_DECREF(ph);
    Py_DECREF(ev);
    return p;
fail:
    PyMem_Free(p);
    Py_DECREF(ph);
    Py_DECREF(ev);
    return NULL;
}

static int parse_work(const struct group *g, struct slot *s, PyObject *work) {
    struct work *out = &s->work;
    memset(out, 0, sizeof(*out));
    long long kind, period, burn_ns, alloc, offset, bound = 0;
    int wall, spin = 0, ring = RING_ALL;
    PyObject *program = Py_None;
    if (!PyArg_ParseTuple(work, "LLLpLL|pLiO", &kind, &period, &burn_ns, &wall, &alloc, &offset, &spin, &bound, &ring, &program)) return -1;
    out->wait_spin = spin;
    out->bound_ns = bound;
    out->ring_mode = ring;
    out->kind = (int)kind;
    out->period_ns = period;
    out->burn_ns = burn_ns;
    out->burn_wall = wall;
    out->alloc_bytes = alloc;
    out->offset_ns = offset;
    if (out->kind == WORK_PERIODIC && out->period_ns <= 0) {
        PyErr_SetString(PyExc_ValueError, "periodic work needs a positive period");
        return -1;
    }
    PyMem_Free(s->prog);
    s->prog = NULL;
    if (out->kind == WORK_PROGRAM) {
        if (program == Py_None) {
            PyErr_SetString(PyExc_ValueError, "program work needs a program");
            return -1;
        }
        if (!(s->prog = parse_program(g, program))) return -1;
    }
    return 0;
}

static struct slot *get_slot(GroupObject *self, unsigned int index) {
    if (index >= self->g.nslots) {
        PyErr_Format(PyExc_IndexError, "slot %u out of range (%u slots)", index, self->g.nslots);
        return NULL;
    }
    return &self->g.slots[index];
}

PyDoc_STRVAR(spawn_doc,
"spawn(index, name, work, policy, priority, nice, cpus, explicit[, extra[, deferred[, after]]])\n\n"
"Create a thread from the calling thread (so it inherits the caller's settings\n"
"unless explicit is true), name it, let it apply its own settings, and park it\n"
"at the start gate.  work is (kind, period_ns, burn_ns, burn_wall, alloc_bytes,\n"
"offset_ns[, wait_spin, bound_ns, ring_mode, program]); extra is (dl_runtime,\n"
"dl_deadline, dl_period, util_min, util_max).  Returns when the thread is created;\n"
"see wait_ready().  deferred: only prepare the slot; a spawn event of another\n"
"thread's program creates the thread mid-run (rt-app's fork).  after: a slot\n"
"created before this one whose thread must have begun its work (after the start)\n"
"before this one begins; -1 (default): none, it begins at the common start.");

static PyObject *Group_spawn(GroupObject *self, PyObject *args) {
    unsigned int index;
    const char *name;
    PyObject *work, *policy, *priority, *nice, *cpus, *extra = Py_None;
    int explicit_defaults, deferred = 0, after = -1;
    if (!PyArg_ParseTuple(args, "IsOOOOOp|Opi", &index, &name, &work, &policy, &priority, &nice, &cpus, &explicit_defaults, &extra,
                          &deferred, &after))
        return NULL;
    struct slot *s = get_slot(self, index);
    if (!s) return NULL;
    if (s->started) {
        PyErr_Format(PyExc_ValueError, "slot %u already has a thread", index);
        return NULL;
    }
    if (after >= (int)index || after < -1 || (after >= 0 && (deferred || self->g.slots[after].deferred))) {
        PyErr_Format(PyExc_ValueError, "slot %u cannot begin after slot %d: only after a slot before it, neither spawned mid-run", index,
                     after);
        return NULL;
    }
    s->after = after;
    if (after >= 0) atomic_store(&self->g.slots[after].follower, 1);
    if (parse_work(&self->g, s, work) || parse_settings(policy, priority, nice, cpus, extra, &s->own)) return NULL;
    snprintf(s->name, sizeof(s->name), "%s", name);
    s->explicit_defaults = explicit_defaults;
    s->deferred = deferred;
    if (deferred) {
        if (s->work.kind != WORK_PROGRAM) {
            PyErr_SetString(PyExc_ValueError, "only a program (kind: phases) can be spawned");
            return NULL;
        }
        Py_RETURN_NONE;
    }
    int rc;
    Py_BEGIN_ALLOW_THREADS
    rc = create_thread(&self->g, s);
    Py_END_ALLOW_THREADS
    if (rc) {
        errno = rc;
        return PyErr_SetFromErrno(PyExc_OSError);
    }
    Py_RETURN_NONE;
}

PyDoc_STRVAR(adopt_doc,
"adopt(index, name, work)\n\nMake the calling thread (the main thread) slot index: record its TID;\n"
"run_main() later runs its work.");

static PyObject *Group_adopt(GroupObject *self, PyObject *args) {
    unsigned int index;
    const char *name;
    PyObject *work;
    if (!PyArg_ParseTuple(args, "IsO", &index, &name, &work)) return NULL;
    struct slot *s = get_slot(self, index);
    if (!s || parse_work(&self->g, s, work)) return NULL;
    snprintf(s->name, sizeof(s->name), "%s", name);
    s->hdr->tid = (int32_t)syscall(SYS_gettid);
    s->own.policy = -1;
    prefault_slot(s);
    if (s->prog && !(s->pstate = program_prepare(s))) s->hdr->err_other = ENOMEM;
    atomic_store((_Atomic int32_t *)&s->hdr->state, ST_READY);
    Py_RETURN_NONE;
}

PyDoc_STRVAR(wait_ready_doc, "wait_ready(timeout_s) -> bool\n\nWait, without the GIL, until every spawned thread is parked at the gate.");

static PyObject *Group_wait_ready(GroupObject *self, PyObject *args) {
    double timeout;
    if (!PyArg_ParseTuple(args, "d", &timeout)) return NULL;
    int ok = 0;
    Py_BEGIN_ALLOW_THREADS
    int64_t until = now_ns(CLOCK_MONOTONIC) + (int64_t)(timeout * 1e9);
    for (;;) {
        ok = 1;
        for (uint32_t i = 0; i < self->g.nslots; i++) {
            struct slot *s = &self->g.slots[i];
            if (s->started && atomic_load((_Atomic int32_t *)&s->hdr->state) < ST_READY) ok = 0;
        }
        if (ok || now_ns(CLOCK_MONOTONIC) > until) break;
        struct timespec ts = {0, 200000};
        nanosleep(&ts, NULL);
    }
    Py_END_ALLOW_THREADS
    return PyBool_FromLong(ok);
}

PyDoc_STRVAR(release_doc, "release(start_ns, end_ns) -> bool\n\nOpen the gate from this process (as open_gate does from the runner): every thread starts its work at start_ns (CLOCK_MONOTONIC) and stops at end_ns.  False if it was open or cancelled already.");

static PyObject *Group_release(GroupObject *self, PyObject *args) {
    long long start, end;
    if (!PyArg_ParseTuple(args, "LL", &start, &end)) return NULL;
    return PyBool_FromLong(gate_open(self->g.base, start, end));
}

PyDoc_STRVAR(run_main_doc, "run_main(index) -> bool\n\nRun the adopted main thread's work in the calling thread, GIL released, once the gate opens.  False if the gate was cancelled instead: nothing ran.");

static PyObject *Group_run_main(GroupObject *self, PyObject *args) {
    unsigned int index;
    if (!PyArg_ParseTuple(args, "I", &index)) return NULL;
    struct slot *s = get_slot(self, index);
    if (!s) return NULL;
    Py_BEGIN_ALLOW_THREADS
    run_slot(s);
    Py_END_ALLOW_THREADS
    program_release(s->pstate);
    s->pstate = NULL;
    return PyBool_FromLong(atomic_load(gate_word(self->g.base)) == GATE_OPEN);
}

PyDoc_STRVAR(join_doc, "join()\n\nJoin every thread, those spawned mid-run too, GIL released.");

static PyObject *Group_join(GroupObject *self, PyObject *Py_UNUSED(ignored)) {
    Py_BEGIN_ALLOW_THREADS
    join_all(&self->g);
    Py_END_ALLOW_THREADS
    Py_RETURN_NONE;
}

PyDoc_STRVAR(errors_doc, "errors(index) -> (tid, err_sched, err_nice, err_cpus, err_other)");

static PyObject *Group_errors(GroupObject *self, PyObject *args) {
    unsigned int index;
    if (!PyArg_ParseTuple(args, "I", &index)) return NULL;
    struct slot *s = get_slot(self, index);
    if (!s) return NULL;
    return Py_BuildValue("(iiiii)", s->hdr->tid, s->hdr->err_sched, s->hdr->err_nice, s->hdr->err_cpus, s->hdr->err_other);
}

static PyMethodDef Group_methods[] = {
    {"spawn", (PyCFunction)Group_spawn, METH_VARARGS, spawn_doc},
    {"adopt", (PyCFunction)Group_adopt, METH_VARARGS, adopt_doc},
    {"wait_ready", (PyCFunction)Group_wait_ready, METH_VARARGS, wait_ready_doc},
    {"release", (PyCFunction)Group_release, METH_VARARGS, release_doc},
    {"run_main", (PyCFunction)Group_run_main, METH_VARARGS, run_main_doc},
    {"join", (PyCFunction)Group_join, METH_NOARGS, join_doc},
    {"errors", (PyCFunction)Group_errors, METH_VARARGS, errors_doc},
    {NULL, NULL, 0, NULL},
};

static PyTypeObject GroupType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "runner.run._probe.Group",
    .tp_doc = PyDoc_STR("Group(buffer, nthreads, capacity, all_cpus): the measured threads of one process."),
    .tp_basicsize = sizeof(GroupObject),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Group_init,
    .tp_dealloc = (destructor)Group_dealloc,
    .tp_methods = Group_methods,
};

/* ----------------------------------------------------------- module functions */

static PyObject *probe_apply(PyObject *mod, PyObject *args) {
    PyObject *policy, *priority, *nice, *cpus, *extra = Py_None;
    if (!PyArg_ParseTuple(args, "OOOO|O", &policy, &priority, &nice, &cpus, &extra)) return NULL;
    struct settings s;
    if (parse_settings(policy, priority, nice, cpus, extra, &s)) return NULL;
    int32_t errs[3];
    apply_settings(&s, errs);
    return Py_BuildValue("(iii)", errs[0], errs[1], errs[2]);
}

PyDoc_STRVAR(buckets_doc,
"buckets(buffer, offset, negated=False, first=0, last=HIST_BUCKETS-1) -> [(low, high, count), ...]\n\n"
"The rows of the histogram of HIST_BUCKETS native uint64 counters at `offset` of `buffer`: the buckets\n"
"that are not zero with the values each holds, ascending (histogram.from_rows, read in place: a cell of\n"
"1,024 threads holds 4,096 histograms of 4,352 counters).  `negated`: the counters are of the negation\n"
"of the values, so the rows are (-high, -low, count), still ascending.  Only counters first..last are\n"
"looked at (the buckets of a finished thread's exact minimum and maximum: the rest are zero).");

static PyObject *bucket_row(int i, int negated, uint64_t count) {
    int64_t low, high;
    hist_bounds(i, &low, &high);
    return Py_BuildValue("(LLK)", (long long)(negated ? -high : low), (long long)(negated ? -low : high), (unsigned long long)count);
}

static PyObject *probe_buckets(PyObject *mod, PyObject *args) {
    PyObject *buffer;
    Py_ssize_t offset;
    int negated = 0, first = 0, last = HIST_BUCKETS - 1;
    if (!PyArg_ParseTuple(args, "On|pii", &buffer, &offset, &negated, &first, &last)) return NULL;
    if (first < 0 || last >= HIST_BUCKETS || first > last + 1) {
        PyErr_Format(PyExc_ValueError, "counters %d..%d are not within 0..%d", first, last, HIST_BUCKETS - 1);
        return NULL;
    }
    Py_buffer view;
    if (PyObject_GetBuffer(buffer, &view, PyBUF_SIMPLE) != 0) return NULL;
    PyObject *out = NULL;
    if (offset < 0 || offset > view.len - (Py_ssize_t)HIST_BUCKETS * 8) {
        PyErr_Format(PyExc_ValueError, "a histogram at %zd does not fit a buffer of %zd bytes", offset, view.len);
        goto done;
    }
    if (!(out = PyList_New(0))) goto done;
    const char *at = (const char *)view.buf + offset;
    for (int k = 0; k <= last - first; k++) {
        int i = negated ? last - k : first + k;
        uint64_t v;
        memcpy(&v, at + (Py_ssize_t)i * 8, 8);
        if (!v) continue;
        PyObject *row = bucket_row(i, negated, v);
        if (!row || PyList_Append(out, row) < 0) {
            Py_XDECREF(row);
            Py_CLEAR(out);
            goto done;
        }
        Py_DECREF(row);
    }
done:
    PyBuffer_Release(&view);
    return out;
}

PyDoc_STRVAR(init_resources_doc,
"init_resources(buffer, specs)\n\n"
"Initialise the shared resources segment: specs is a sequence of (kind, protocol, parties, period_ns),\n"
"one per RES_BYTES record.  Mutexes, conditions and their internal locks are process-shared;\n"
"protocol 1 makes a mutex priority-inheriting, QUEUE_DROP a queue drop the resumes no thread waits for (rt-app's);\n"
"conditions wait on CLOCK_MONOTONIC.");

static PyObject *probe_init_resources(PyObject *mod, PyObject *args) {
    PyObject *buffer, *specs;
    if (!PyArg_ParseTuple(args, "OO", &buffer, &specs)) return NULL;
    Py_buffer view;
    if (PyObject_GetBuffer(buffer, &view, PyBUF_WRITABLE) != 0) return NULL;
    PyObject *seq = PySequence_Fast(specs, "specs must be a sequence");
    if (!seq) {
        PyBuffer_Release(&view);
        return NULL;
    }
    Py_ssize_t n = PySequence_Fast_GET_SIZE(seq);
    int rc = 0;
    if (view.len < n * RES_BYTES) {
        PyErr_Format(PyExc_ValueError, "resources segment holds %zd bytes, %zd needed", view.len, n * RES_BYTES);
        goto done;
    }
    for (Py_ssize_t i = 0; i < n; i++) {
        struct resource *r = (struct resource *)((char *)view.buf + i * RES_BYTES);
        int kind, protocol, parties;
        long long period;
        if (!PyArg_ParseTuple(PySequence_Fast_GET_ITEM(seq, i), "iiiL", &kind, &protocol, &parties, &period)) goto done;
        memset(r, 0, RES_BYTES);
        r->kind = kind;
        r->protocol = protocol;
        r->parties = parties;
        r->period = period;
        r->owner = -1;
        pthread_mutexattr_t ma;
        pthread_mutexattr_init(&ma);
        pthread_mutexattr_setpshared(&ma, PTHREAD_PROCESS_SHARED);
        /* A worker that dies holding it (killed, crashed) must not leave its peers blocked on it for good. */
        pthread_mutexattr_setrobust(&ma, PTHREAD_MUTEX_ROBUST);
        if (kind != RES_MUTEX || protocol == 1) rc = pthread_mutexattr_setprotocol(&ma, PTHREAD_PRIO_INHERIT);
        if (!rc) rc = pthread_mutex_init(&r->m, &ma);
        pthread_mutexattr_destroy(&ma);
        pthread_condattr_t ca;
        pthread_condattr_init(&ca);
        pthread_condattr_setpshared(&ca, PTHREAD_PROCESS_SHARED);
        pthread_condattr_setclock(&ca, CLOCK_MONOTONIC);
        if (!rc) rc = pthread_cond_init(&r->c, &ca);
        pthread_condattr_destroy(&ca);
        if (rc) {
            errno = rc;
            PyErr_SetFromErrno(PyExc_OSError);
            goto done;
        }
    }
done:
    Py_DECREF(seq);
    PyBuffer_Release(&view);
    if (PyErr_Occurred()) return NULL;
    Py_RETURN_NONE;
}

PyDoc_STRVAR(getattr_doc,
"sched_getattr(tid) -> (policy, flags, nice, priority, runtime_ns, deadline_ns, period_ns, util_min, util_max)\n\n"
"A thread's scheduling attributes as the kernel holds them (sched_getattr(2)), SCHED_DEADLINE's included.");

static PyObject *probe_sched_getattr(PyObject *mod, PyObject *args) {
    int tid;
    if (!PyArg_ParseTuple(args, "i", &tid)) return NULL;
    struct sched_attr_k a;
    memset(&a, 0, sizeof(a));
    if (syscall(SYS_sched_getattr, tid, &a, sizeof(a), 0) != 0) return PyErr_SetFromErrno(PyExc_OSError);
    return Py_BuildValue("(iKiiKKKII)", (int)a.sched_policy, (unsigned long long)a.sched_flags, a.sched_nice, (int)a.sched_priority,
                         (unsigned long long)a.sched_runtime, (unsigned long long)a.sched_deadline, (unsigned long long)a.sched_period,
                         a.sched_util_min, a.sched_util_max);
}

static PyObject *probe_set_name(PyObject *mod, PyObject *args) {
    const char *name;
    if (!PyArg_ParseTuple(args, "s", &name)) return NULL;
    if (prctl(PR_SET_NAME, name, 0, 0, 0) != 0) return PyErr_SetFromErrno(PyExc_OSError);
    Py_RETURN_NONE;
}

static PyObject *probe_lock_memory(PyObject *mod, PyObject *Py_UNUSED(ignored)) {
    if (mlockall(MCL_CURRENT | MCL_FUTURE) != 0) return PyErr_SetFromErrno(PyExc_OSError);
    /* As the ros2-realtime-examples: keep freed heap mapped and locked, never mmap a block. */
    if (mallopt(M_TRIM_THRESHOLD, -1) == 0 || mallopt(M_MMAP_MAX, 0) == 0) {
        munlockall();
        PyErr_SetString(PyExc_OSError, "mallopt failed");
        return NULL;
    }
    Py_RETURN_NONE;
}

static PyObject *probe_preallocate(PyObject *mod, PyObject *args) {
    long long bytes;
    if (!PyArg_ParseTuple(args, "L", &bytes)) return NULL;
    long page = sysconf(_SC_PAGESIZE);
    void *buf = NULL;
    int rc = posix_memalign(&buf, (size_t)page, (size_t)bytes);
    if (rc) {
        errno = rc;
        return PyErr_SetFromErrno(PyExc_OSError);
    }
    for (long long off = 0; off < bytes; off += page) ((volatile char *)buf)[off] = 0;
    free(buf);
    Py_RETURN_NONE;
}

static PyObject *probe_set_default_stacksize(PyObject *mod, PyObject *args) {
    long long bytes;
    if (!PyArg_ParseTuple(args, "L", &bytes)) return NULL;
    pthread_attr_t attr;
    int rc = pthread_getattr_default_np(&attr);
    if (!rc) rc = pthread_attr_setstacksize(&attr, (size_t)bytes);
    if (!rc) rc = pthread_setattr_default_np(&attr);
    pthread_attr_destroy(&attr);
    if (rc) {
        errno = rc;
        return PyErr_SetFromErrno(PyExc_OSError);
    }
    Py_RETURN_NONE;
}

static PyObject *probe_install_stop_handler(PyObject *mod, PyObject *Py_UNUSED(ignored)) {
    if (g_stop_pipe[0] < 0 && pipe2(g_stop_pipe, O_CLOEXEC | O_NONBLOCK) != 0) return PyErr_SetFromErrno(PyExc_OSError);
    struct sigaction sa;
    memset(&sa, 0, sizeof(sa));
    sa.sa_handler = on_stop_signal;
    sigemptyset(&sa.sa_mask);
    sigaction(SIGTERM, &sa, NULL);
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGUSR1, &sa, NULL);
    Py_RETURN_NONE;
}

static PyObject *probe_set_pdeathsig(PyObject *mod, PyObject *args) {
    int sig;
    if (!PyArg_ParseTuple(args, "i", &sig)) return NULL;
    if (prctl(PR_SET_PDEATHSIG, sig, 0, 0, 0) != 0) return PyErr_SetFromErrno(PyExc_OSError);
    Py_RETURN_NONE;
}

PyDoc_STRVAR(apply_to_doc,
"apply_to(tid, policy, priority, nice, cpus[, extra]) -> (err_sched, err_nice, err_cpus)\n\n"
"Apply settings to another thread (a program's thread a rule matched), as apply() does to the caller.");

static PyObject *probe_apply_to(PyObject *mod, PyObject *args) {
    int tid;
    PyObject *policy, *priority, *nice, *cpus, *extra = Py_None;
    if (!PyArg_ParseTuple(args, "iOOOO|O", &tid, &policy, &priority, &nice, &cpus, &extra)) return NULL;
    struct settings s;
    if (parse_settings(policy, priority, nice, cpus, extra, &s)) return NULL;
    int32_t errs[3];
    Py_BEGIN_ALLOW_THREADS
    apply_settings_to(tid, &s, 0, errs);
    Py_END_ALLOW_THREADS
    return Py_BuildValue("(iii)", errs[0], errs[1], errs[2]);
}

/* Stages a program's start reports on its report pipe, each as (stage, errno). */
#define STAGE_CWD 1
#define STAGE_EXEC 2

static char **byte_strings(PyObject *seq_in, const char *what) {
    PyObject *seq = PySequence_Fast(seq_in, what);
    if (!seq) return NULL;
    Py_ssize_t n = PySequence_Fast_GET_SIZE(seq);
    char **out = PyMem_Calloc((size_t)n + 1, sizeof(char *));
    if (!out) {
        Py_DECREF(seq);
        PyErr_NoMemory();
        return NULL;
    }
    for (Py_ssize_t i = 0; i < n; i++) {
        PyObject *item = PySequence_Fast_GET_ITEM(seq, i);
        if (!PyBytes_Check(item)) {
            PyErr_Format(PyExc_TypeError, "%s: item %zd is not bytes", what, i);
            goto fail;
        }
        const char *text = PyBytes_AS_STRING(item);
        out[i] = PyMem_Malloc((size_t)PyBytes_GET_SIZE(item) + 1);
        if (!out[i]) {
            PyErr_NoMemory();
            goto fail;
        }
        memcpy(out[i], text, (size_t)PyBytes_GET_SIZE(item) + 1);
    }
    Py_DECREF(seq);
    return out;
fail:
    for (Py_ssize_t i = 0; i < n; i++) PyMem_Free(out[i]);
    PyMem_Free(out);
    Py_DECREF(seq);
    return NULL;
}

static void free_strings(char **v) {
    if (!v) return;
    for (char **p = v; *p; p++) PyMem_Free(*p);
    PyMem_Free(v);
}

/* Close every descriptor from 3 up but `keep`: close_range(2) where the kernel has it, one by one where not. */
static void close_others(int keep, long maxfd) {
#ifdef SYS_close_range
    if ((keep <= 3 || syscall(SYS_close_range, 3U, (unsigned)keep - 1, 0U) == 0) && syscall(SYS_close_range, (unsigned)keep + 1, ~0U, 0U) == 0) return;
#endif
    for (int fd = 3; fd < maxfd; fd++) {
        if (fd != keep) close(fd);
    }
}

/* Close every descriptor from 3 up but the `n` in `keep` (at most 8): between fork and exec, so that a child
 * holds no end of another pipe of the runner's (the write end of its own gate, or of another program's). */
static void close_all_but(const int *keep, int n, long maxfd) {
    int k[8], m = 0;
    for (int i = 0; i < n && m < 8; i++) {
        if (keep[i] < 3) continue;
        int j = m++;
        while (j > 0 && k[j - 1] > keep[i]) {
            k[j] = k[j - 1];
            j--;
        }
        k[j] = keep[i];
    }
    int from = 3;
    for (int i = 0; i <= m; i++) {
        int to = i < m ? k[i] - 1 : -1; /* -1: to the last descriptor */
        if (to < 0 || to >= from) {
#ifdef SYS_close_range
            if (syscall(SYS_close_range, (unsigned)from, to < 0 ? ~0U : (unsigned)to, 0U) != 0)
#endif
                for (long fd = from; fd < (to < 0 ? maxfd : to + 1); fd++) close((int)fd);
        }
        if (i < m) from = k[i] + 1;
    }
}

static void write_all(int fd, const void *buf, size_t len) {
    const char *p = buf;
    while (len) {
        ssize_t w = write(fd, p, len);
        if (w < 0 && errno == EINTR) continue;
        if (w <= 0) return;
        p += w;
        len -= (size_t)w;
    }
}

PyDoc_STRVAR(spawn_program_doc,
"spawn_program(path, argv, envp, cwd, settings, reset_on_fork, out_fd, err_fd) -> (pid, report_fd, gate_fd)\n\n"
"Fork a child that leads its own process group, dies with the runner (PR_SET_PDEATHSIG), applies\n"
"`settings` (policy, priority, nice, cpus, extra) to itself, writes their three errnos to report_fd,\n"
"then waits for a byte on gate_fd before it execs `path` (bytes; argv and envp lists of bytes; cwd\n"
"bytes or None) with stdin from /dev/null and stdout/stderr on the given fds.  A failed chdir or exec\n"
"writes (stage, errno) to report_fd and exits 127; report_fd reaches end of file at a successful exec.\n"
"Closing gate_fd without a byte makes the child exit 0 without exec.  Only async-signal-safe calls\n"
"run between fork and exec: everything is built before the fork.");

static PyObject *probe_spawn_program(PyObject *mod, PyObject *args) {
    PyObject *path_o, *argv_o, *envp_o, *cwd_o, *settings_o;
    int reset_on_fork, out_fd, err_fd;
    if (!PyArg_ParseTuple(args, "SOOOOpii", &path_o, &argv_o, &envp_o, &cwd_o, &settings_o, &reset_on_fork, &out_fd, &err_fd)) return NULL;
    PyObject *policy, *priority, *nice, *cpus, *extra = Py_None;
    if (!PyArg_ParseTuple(settings_o, "OOOO|O", &policy, &priority, &nice, &cpus, &extra)) return NULL;
    struct settings s;
    if (parse_settings(policy, priority, nice, cpus, extra, &s)) return NULL;
    if (cwd_o != Py_None && !PyBytes_Check(cwd_o)) return PyErr_Format(PyExc_TypeError, "cwd must be bytes or None");
    char **argv = byte_strings(argv_o, "argv");
    if (!argv) return NULL;
    char **envp = byte_strings(envp_o, "envp");
    if (!envp) {
        free_strings(argv);
        return NULL;
    }
    const char *path = PyBytes_AS_STRING(path_o);
    const char *cwd = cwd_o == Py_None ? NULL : PyBytes_AS_STRING(cwd_o);
    int report[2] = {-1, -1}, gate[2] = {-1, -1};
    int devnull = open("/dev/null", O_RDONLY | O_CLOEXEC);
    if (devnull < 0 || pipe2(report, O_CLOEXEC) != 0 || pipe2(gate, O_CLOEXEC) != 0) {
        PyErr_SetFromErrno(PyExc_OSError);
        goto fail;
    }
    pid_t parent = getpid();
    long maxfd = sysconf(_SC_OPEN_MAX);
    if (maxfd < 0 || maxfd > 65536) maxfd = 65536;
    pid_t pid = fork();
    if (pid < 0) {
        PyErr_SetFromErrno(PyExc_OSError);
        goto fail;
    }
    if (pid == 0) {
        setpgid(0, 0);
        prctl(PR_SET_PDEATHSIG, SIGKILL, 0, 0, 0);
        if (getppid() != parent) _exit(0); /* the runner died before the line above */
        /* Its gate's write end, held here, would keep its read from ever seeing the runner close it. */
        const int keep[] = {report[1], gate[0], devnull, out_fd, err_fd};
        close_all_but(keep, 5, maxfd);
        struct sigaction dfl;
        memset(&dfl, 0, sizeof(dfl));
        dfl.sa_handler = SIG_DFL;
        for (int sig = 1; sig < NSIG; sig++) sigaction(sig, &dfl, NULL);
        sigset_t none;
        sigemptyset(&none);
        sigprocmask(SIG_SETMASK, &none, NULL);
        int32_t errs[3];
        apply_settings_to(0, &s, reset_on_fork, errs);
        write_all(report[1], errs, sizeof(errs));
        char go;
        ssize_t got;
        do got = read(gate[0], &go, 1);
        while (got < 0 && errno == EINTR);
        if (got != 1) _exit(0); /* the runner gave up on the cell before the program's start */
        if (dup2(devnull, 0) < 0 || dup2(out_fd, 1) < 0 || dup2(err_fd, 2) < 0) {
            int32_t r[2] = {STAGE_EXEC, errno};
            write_all(report[1], r, sizeof(r));
            _exit(127);
        }
        close_others(report[1], maxfd);
        if (cwd && chdir(cwd) != 0) {
            int32_t r[2] = {STAGE_CWD, errno};
            write_all(report[1], r, sizeof(r));
            _exit(127);
        }
        execve(path, argv, envp);
        int32_t r[2] = {STAGE_EXEC, errno};
        write_all(report[1], r, sizeof(r));
        _exit(127);
    }
    close(report[1]);
    close(gate[0]);
    close(devnull);
    free_strings(argv);
    free_strings(envp);
    return Py_BuildValue("(iii)", (int)pid, report[0], gate[1]);
fail:
    for (int k = 0; k < 2; k++) {
        if (report[k] >= 0) close(report[k]);
        if (gate[k] >= 0) close(gate[k]);
    }
    if (devnull >= 0) close(devnull);
    free_strings(argv);
    free_strings(envp);
    return NULL;
}

static PyObject *probe_stopped(PyObject *mod, PyObject *Py_UNUSED(ignored)) {
    return PyBool_FromLong(g_stop);
}

/* The runner's side of a worker's start gate: its writable mapping of the buffer's file header. */
static char *gate_header(PyObject *buffer, Py_buffer *view) {
    if (PyObject_GetBuffer(buffer, view, PyBUF_WRITABLE) != 0) return NULL;
    if (view->len < FILE_HEADER) {
        PyErr_Format(PyExc_ValueError, "a buffer's header is %d bytes, this one %zd", FILE_HEADER, view->len);
        PyBuffer_Release(view);
        return NULL;
    }
    return view->buf;
}

PyDoc_STRVAR(open_gate_doc,
"open_gate(header, start_ns, end_ns) -> bool\n\n"
"Open a worker's start gate (header: a writable mapping of its buffer's first bytes): every thread waiting at it\n"
"is woken at once, at its own policy, to start at start_ns (CLOCK_MONOTONIC) and stop at end_ns.  False if the\n"
"gate was open or cancelled already.");

static PyObject *probe_open_gate(PyObject *mod, PyObject *args) {
    PyObject *buffer;
    long long start, end;
    if (!PyArg_ParseTuple(args, "OLL", &buffer, &start, &end)) return NULL;
    Py_buffer view;
    char *base = gate_header(buffer, &view);
    if (!base) return NULL;
    int opened = gate_open(base, start, end);
    PyBuffer_Release(&view);
    return PyBool_FromLong(opened);
}

PyDoc_STRVAR(cancel_gate_doc,
"cancel_gate(header) -> bool\n\n"
"Cancel a worker's start gate that is still shut: its threads (and those that reach it later) leave without\n"
"working.  True if it is cancelled now, False if it had been opened.");

static PyObject *probe_cancel_gate(PyObject *mod, PyObject *args) {
    PyObject *buffer;
    if (!PyArg_ParseTuple(args, "O", &buffer)) return NULL;
    Py_buffer view;
    char *base = gate_header(buffer, &view);
    if (!base) return NULL;
    int cancelled = gate_cancel(base);
    PyBuffer_Release(&view);
    return PyBool_FromLong(cancelled);
}

/* ------------------------------------------------------------------ Watchdog */

/*
 * The runner's deadline, enforced from outside the measured threads: a native
 * thread, at the highest RT priority the runner may use, that needs no GIL and
 * so still runs when RT threads starve the runner's Python threads.  When the
 * deadline passes it SIGKILLs every registered process group.
 */
typedef struct {
    PyObject_HEAD
    pthread_t thread;
    pthread_mutex_t lock;
    pthread_cond_t cond;
    int64_t deadline_ns;   /* 0: disarmed */
    Py_ssize_t npids;
    pid_t *pids;           /* every process group it kills at the deadline, however many (malloc'd; NULL: none) */
    int fired;
    int quit;
    int running;
    int rt_priority;       /* what the thread got; 0 if it stayed SCHED_OTHER */
} WatchdogObject;

static void *watchdog_main(void *arg) {
    WatchdogObject *w = arg;
    prctl(PR_SET_NAME, "runner-watchdog", 0, 0, 0);
    pthread_mutex_lock(&w->lock);
    while (!w->quit) {
        if (w->deadline_ns == 0) {
            pthread_cond_wait(&w->cond, &w->lock);
            continue;
        }
        struct timespec ts = to_ts(w->deadline_ns);
        int rc = pthread_cond_timedwait(&w->cond, &w->lock, &ts);
        if (rc == ETIMEDOUT && w->deadline_ns && now_ns(CLOCK_MONOTONIC) >= w->deadline_ns) {
            for (Py_ssize_t i = 0; i < w->npids; i++) kill(-w->pids[i], SIGKILL);
            for (Py_ssize_t i = 0; i < w->npids; i++) kill(w->pids[i], SIGKILL);
            w->fired = 1;
            w->deadline_ns = 0;
        }
    }
    pthread_mutex_unlock(&w->lock);
    return NULL;
}

static int Watchdog_init(WatchdogObject *self, PyObject *args, PyObject *kwds) {
    static char *kwlist[] = {"rt_priority", NULL};
    int prio = 99;
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "|i", kwlist, &prio)) return -1;
    pthread_condattr_t ca;
    pthread_condattr_init(&ca);
    pthread_condattr_setclock(&ca, CLOCK_MONOTONIC);
    pthread_cond_init(&self->cond, &ca);
    pthread_condattr_destroy(&ca);
    pthread_mutex_init(&self->lock, NULL);
    pthread_attr_t attr;
    pthread_attr_init(&attr);
    pthread_attr_setstacksize(&attr, 64 * 1024);
    int rc = -1;
    if (prio > 0) {
        struct sched_param p = {.sched_priority = prio};
        pthread_attr_setinheritsched(&attr, PTHREAD_EXPLICIT_SCHED);
        pthread_attr_setschedpolicy(&attr, SCHED_FIFO);
        pthread_attr_setschedparam(&attr, &p);
        rc = pthread_create(&self->thread, &attr, watchdog_main, self);
        if (rc == 0) self->rt_priority = prio;
    }
    if (rc != 0) { /* no right to RT: a plain thread still enforces the deadline, just less surely */
        pthread_attr_setinheritsched(&attr, PTHREAD_INHERIT_SCHED);
        rc = pthread_create(&self->thread, &attr, watchdog_main, self);
    }
    pthread_attr_destroy(&attr);
    if (rc) {
        errno = rc;
        PyErr_SetFromErrno(PyExc_OSError);
        return -1;
    }
    self->running = 1;
    return 0;
}

static PyObject *Watchdog_arm(WatchdogObject *self, PyObject *args) {
    long long deadline;
    PyObject *pids;
    if (!PyArg_ParseTuple(args, "LO", &deadline, &pids)) return NULL;
    PyObject *seq = PySequence_Fast(pids, "pids must be a sequence");
    if (!seq) return NULL;
    Py_ssize_t n = PySequence_Fast_GET_SIZE(seq);
    pid_t *list = PyMem_RawMalloc((size_t)(n ? n : 1) * sizeof(pid_t));
    if (!list) {
        Py_DECREF(seq);
        return PyErr_NoMemory();
    }
    for (Py_ssize_t i = 0; i < n; i++) {
        long pid = PyLong_AsLong(PySequence_Fast_GET_ITEM(seq, i));
        if (pid == -1 && PyErr_Occurred()) break;
        if (pid <= 0 || pid > INT_MAX) { /* kill(-0) or kill(-1) would signal far more than the cell */
            PyErr_Format(PyExc_ValueError, "pid %ld: expected a process id above 0", pid);
            break;
        }
        list[i] = (pid_t)pid;
    }
    Py_DECREF(seq);
    if (PyErr_Occurred()) {
        PyMem_RawFree(list);
        return NULL;
    }
    pthread_mutex_lock(&self->lock);
    pid_t *old = self->pids;
    self->pids = list;
    self->npids = n;
    self->deadline_ns = deadline;
    self->fired = 0;
    pthread_cond_broadcast(&self->cond);
    pthread_mutex_unlock(&self->lock);
    PyMem_RawFree(old);
    Py_RETURN_NONE;
}

static PyObject *Watchdog_disarm(WatchdogObject *self, PyObject *Py_UNUSED(ignored)) {
    pthread_mutex_lock(&self->lock);
    self->deadline_ns = 0;
    self->npids = 0;
    pid_t *old = self->pids;
    self->pids = NULL;
    pthread_cond_broadcast(&self->cond);
    pthread_mutex_unlock(&self->lock);
    PyMem_RawFree(old);
    Py_RETURN_NONE;
}

static PyObject *Watchdog_close(WatchdogObject *self, PyObject *Py_UNUSED(ignored)) {
    if (self->running) {
        pthread_mutex_lock(&self->lock);
        self->quit = 1;
        pthread_cond_broadcast(&self->cond);
        pthread_mutex_unlock(&self->lock);
        Py_BEGIN_ALLOW_THREADS
        pthread_join(self->thread, NULL);
        Py_END_ALLOW_THREADS
        self->running = 0;
    }
    Py_RETURN_NONE;
}

static PyObject *Watchdog_get_fired(WatchdogObject *self, void *closure) { return PyBool_FromLong(self->fired); }
static PyObject *Watchdog_get_prio(WatchdogObject *self, void *closure) { return PyLong_FromLong(self->rt_priority); }

static void Watchdog_dealloc(WatchdogObject *self) {
    PyObject *r = Watchdog_close(self, NULL);
    Py_XDECREF(r);
    PyMem_RawFree(self->pids);
    pthread_mutex_destroy(&self->lock);
    pthread_cond_destroy(&self->cond);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

static PyMethodDef Watchdog_methods[] = {
    {"arm", (PyCFunction)Watchdog_arm, METH_VARARGS, "arm(deadline_ns, pids): SIGKILL these process groups at deadline_ns (CLOCK_MONOTONIC)"},
    {"disarm", (PyCFunction)Watchdog_disarm, METH_NOARGS, "disarm(): forget the deadline"},
    {"close", (PyCFunction)Watchdog_close, METH_NOARGS, "close(): stop the watchdog thread"},
    {NULL, NULL, 0, NULL},
};

static PyGetSetDef Watchdog_getset[] = {
    {"fired", (getter)Watchdog_get_fired, NULL, "True once the deadline passed and the processes were killed", NULL},
    {"rt_priority", (getter)Watchdog_get_prio, NULL, "SCHED_FIFO priority of the watchdog thread, 0 if none", NULL},
    {NULL},
};

static PyTypeObject WatchdogType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "runner.run._probe.Watchdog",
    .tp_doc = PyDoc_STR("Watchdog(rt_priority=99): kills registered process groups when a deadline passes."),
    .tp_basicsize = sizeof(WatchdogObject),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Watchdog_init,
    .tp_dealloc = (destructor)Watchdog_dealloc,
    .tp_methods = Watchdog_methods,
    .tp_getset = Watchdog_getset,
};

/* Every event kind of records.h as EV_<NAME>, EV_COUNT (one past the last code), and EVENT_KINDS: {NAME: code}. */
static int add_event_kinds(PyObject *m) {
    PyObject *kinds = PyDict_New();
    if (!kinds) return -1;
#define ADD_KIND(name, needs)                                                                                             \
    if (PyModule_AddIntConstant(m, "EV_" #name, EV_##name) < 0) goto fail;                                                \
    {                                                                                                                     \
        PyObject *code = PyLong_FromLong(EV_##name);                                                                      \
        int rc = code ? PyDict_SetItemString(kinds, #name, code) : -1;                                                    \
        Py_XDECREF(code);                                                                                                 \
        if (rc < 0) goto fail;                                                                                            \
    }
    EVENT_KINDS(ADD_KIND)
#undef ADD_KIND
    if (PyModule_AddIntConstant(m, "EV_COUNT", EV_COUNT) < 0) goto fail;
    return PyModule_AddObject(m, "EVENT_KINDS", kinds) < 0 ? (Py_DECREF(kinds), -1) : 0;
fail:
    Py_DECREF(kinds);
    return -1;
}

PyDoc_STRVAR(records_doc,
"records() -> {record: (size, ((field, offset, size, format), ...))}\n\n"
"The records of the shared buffer as the C core declares them (records.h): for each, its size in bytes\n"
"(its reserved tail included) and its fields in order, each with its offset, size and struct format\n"
"(\"q\", \"4q\": little endian, no padding).  runner/run/records.py reads every field by name from it.");

static PyObject *probe_records(PyObject *mod, PyObject *Py_UNUSED(ignored)) {
    PyObject *out = PyDict_New();
    for (int r = 0; out && r < native_nrecords; r++) {
        const struct record_table *t = &native_records[r];
        PyObject *fields = PyTuple_New(t->nfields), *entry = NULL;
        for (int i = 0; fields && i < t->nfields; i++) {
            const struct record_field *f = &t->fields[i];
            PyObject *row = f->count == 1 ? Py_BuildValue("(snns)", f->name, (Py_ssize_t)f->offset, (Py_ssize_t)f->size, f->code)
                                          : Py_BuildValue("(snnN)", f->name, (Py_ssize_t)f->offset, (Py_ssize_t)f->size,
                                                          PyUnicode_FromFormat("%d%s", f->count, f->code));
            if (!row) Py_CLEAR(fields);
            else PyTuple_SET_ITEM(fields, i, row);
        }
        if (fields) entry = Py_BuildValue("(nN)", (Py_ssize_t)t->size, fields);
        if (!entry || PyDict_SetItemString(out, t->name, entry) < 0) Py_CLEAR(out);
        Py_XDECREF(entry);
    }
    return out;
}

static PyMethodDef module_methods[] = {
    {"apply", probe_apply, METH_VARARGS, "apply(policy, priority, nice, cpus[, extra]) -> (err_sched, err_nice, err_cpus) for the calling thread"},
    {"init_resources", probe_init_resources, METH_VARARGS, init_resources_doc},
    {"buckets", probe_buckets, METH_VARARGS, buckets_doc},
    {"sched_getattr", probe_sched_getattr, METH_VARARGS, getattr_doc},
    {"set_name", probe_set_name, METH_VARARGS, "set_name(name): prctl(PR_SET_NAME) on the calling thread"},
    {"lock_memory", probe_lock_memory, METH_NOARGS, "mlockall(MCL_CURRENT|MCL_FUTURE), no heap trimming, no mmap'd blocks"},
    {"preallocate", probe_preallocate, METH_VARARGS, "preallocate(bytes): grow the heap by bytes, fault it in, keep it"},
    {"set_default_stacksize", probe_set_default_stacksize, METH_VARARGS, "default stack size of threads created later"},
    {"install_stop_handler", probe_install_stop_handler, METH_NOARGS, "SIGTERM/SIGINT/SIGUSR1 stop every loop of this process"},
    {"set_pdeathsig", probe_set_pdeathsig, METH_VARARGS, "set_pdeathsig(sig): receive sig when the parent dies"},
    {"stopped", probe_stopped, METH_NOARGS, "True once a stop signal arrived"},
    {"open_gate", probe_open_gate, METH_VARARGS, open_gate_doc},
    {"cancel_gate", probe_cancel_gate, METH_VARARGS, cancel_gate_doc},
    {"apply_to", probe_apply_to, METH_VARARGS, apply_to_doc},
    {"spawn_program", probe_spawn_program, METH_VARARGS, spawn_program_doc},
    {"records", probe_records, METH_NOARGS, records_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef probe_module = {
    PyModuleDef_HEAD_INIT, "runner.run._probe",
    "Native core of the runner: GIL-free measured threads and the deadline watchdog.", -1, module_methods,
};

PyMODINIT_FUNC PyInit__probe(void) {
    if (PyType_Ready(&GroupType) < 0 || PyType_Ready(&WatchdogType) < 0) return NULL;
    PyObject *m = PyModule_Create(&probe_module);
    if (!m) return NULL;
    Py_INCREF(&GroupType);
    PyModule_AddObject(m, "Group", (PyObject *)&GroupType);
    Py_INCREF(&WatchdogType);
    PyModule_AddObject(m, "Watchdog", (PyObject *)&WatchdogType);
    PyModule_AddIntConstant(m, "FILE_HEADER", FILE_HEADER);
    /* the interposer's file (roscb.h): what runner/run/roscb.py writes in its header and checks when it reads it */
    PyModule_AddIntConstant(m, "ROSCB_MAGIC", (long)ROSCB_MAGIC);
    PyModule_AddIntConstant(m, "ROSCB_VERSION", ROSCB_VERSION);
    PyModule_AddIntConstant(m, "ROSCB_PROC_BYTES", ROSCB_PROC_BYTES);
    PyModule_AddIntConstant(m, "ROSCB_STRING_MAX", ROSCB_STRING_MAX);
    PyModule_AddIntConstant(m, "ROSCB_STACK", ROSCB_STACK);
#define ADD_META(name, code) PyModule_AddIntConstant(m, "ROSCB_META_" #name, code);
    ROSCB_META_KINDS(ADD_META)
#undef ADD_META
    PyModule_AddIntConstant(m, "SLOT_GATE_AT", offsetof(struct slot_header, gate_ns));
    PyModule_AddIntConstant(m, "STAGE_CWD", STAGE_CWD);
    PyModule_AddIntConstant(m, "STAGE_EXEC", STAGE_EXEC);
    PyModule_AddIntConstant(m, "SLOT_HEADER", SLOT_HEADER);
    PyModule_AddIntConstant(m, "SAMPLE_SIZE", sizeof(struct sample));
    PyModule_AddIntConstant(m, "LOCK_WAIT_SIZE", sizeof(struct lock_wait));
    PyModule_AddIntConstant(m, "MAX_LOCK_SLOTS", MAX_LOCK_SLOTS);
    PyModule_AddIntConstant(m, "HIST_BUCKETS", HIST_BUCKETS);
    PyModule_AddIntConstant(m, "HIST_SUB_BITS", HIST_SUB_BITS);
    PyModule_AddIntConstant(m, "HIST_SETS", HIST_SETS);
    PyModule_AddIntConstant(m, "RING_NONE", RING_NONE);
    PyModule_AddIntConstant(m, "RING_ALL", RING_ALL);
    PyModule_AddIntConstant(m, "RING_OUTLIERS", RING_OUTLIERS);
    PyModule_AddIntConstant(m, "WORK_SLEEP", WORK_SLEEP);
    PyModule_AddIntConstant(m, "WORK_PERIODIC", WORK_PERIODIC);
    PyModule_AddIntConstant(m, "WORK_SPIN", WORK_SPIN);
    PyModule_AddIntConstant(m, "WORK_PROGRAM", WORK_PROGRAM);
    PyModule_AddIntConstant(m, "MAX_PHASES", MAX_PHASES);
    PyModule_AddIntConstant(m, "MAX_EVENTS", MAX_EVENTS);
    PyModule_AddIntConstant(m, "EV_HDR", EV_HDR);
    PyModule_AddIntConstant(m, "PHASE_BYTES", PHASE_BYTES);
    PyModule_AddIntConstant(m, "RES_BYTES", RES_BYTES);
    PyModule_AddIntConstant(m, "QDEPTH", QDEPTH);
    if (add_event_kinds(m) < 0) return NULL;
    PyModule_AddIntConstant(m, "RES_MUTEX", RES_MUTEX);
    PyModule_AddIntConstant(m, "RES_COND", RES_COND);
    PyModule_AddIntConstant(m, "RES_BARRIER", RES_BARRIER);
    PyModule_AddIntConstant(m, "RES_QUEUE", RES_QUEUE);
    PyModule_AddIntConstant(m, "RES_TIMER", RES_TIMER);
    PyModule_AddIntConstant(m, "QUEUE_KEEP", QUEUE_KEEP);
    PyModule_AddIntConstant(m, "QUEUE_DROP", QUEUE_DROP);
    PyModule_AddIntConstant(m, "OVR_SKIP", OVR_SKIP);
    PyModule_AddIntConstant(m, "OVR_REBASE", OVR_REBASE);
    PyModule_AddIntConstant(m, "OVR_CATCHUP", OVR_CATCHUP);
    return m;
}

