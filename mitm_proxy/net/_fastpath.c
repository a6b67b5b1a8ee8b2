/* The proxy's compiled fast path (mitm_proxy/net/native_udp.py drives it; docs in mitm_proxy/README.md).
 *
 * One Route per receiving UDP socket. drain() reads a batch of datagrams (recvmmsg on Linux), walks each
 * datagram's frames (MAVLink 1 and 2, signed or not: header, length and CRC with the message's CRC_EXTRA),
 * and a datagram that is nothing but valid frames of known message ids nobody wants (the wanted set is
 * Python's: stages, observers, rules decide it) is sent on as it came, byte for byte, to every target
 * (sendmmsg). Everything else - garbage, unknown ids, a wanted frame, a stranger's datagram - goes up to
 * Python unchanged, where the pure-Python path handles it exactly as without this module.
 *
 * A wanted id may be narrowed by a field filter (mitm_proxy/core/pipeline.py, the module doc): a one-byte
 * payload field and the values that make a frame wanted (e.g. DISTANCE_SENSOR's sensor id: an attack on a
 * few sensors does not want the others). An unsigned frame of such an id whose byte holds none of them
 * stays here like an unwanted one; a payload MAVLink 2 truncated before the byte reads 0 there, as the
 * decoder pads it. A signed frame of a filtered id goes up (the pipeline counts it as wanted).
 *
 * Order is kept: drain() stops at the first datagram that goes up, after sending the ones before it, and
 * returns it; the rest of the batch waits in the route for the next drain() call.
 *
 * The check here only ever says "fast" for datagrams the Python splitter (mavframe/frames.py) would also
 * find clean: where that splitter needs more thought (an unknown id, a magic byte inside a signature
 * block), the datagram goes up.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <arpa/inet.h>
#include <errno.h>
#include <math.h>
#include <netinet/in.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <time.h>

#define BATCH 64
#define MAX_DATAGRAM 8192            /* endpoints.MAX_DATAGRAM_BYTES: longer ones go up, to be counted */
#define BUF_LEN (MAX_DATAGRAM + 1)
#define MAX_TARGETS 16
#define IDS 65536                    /* ids at or above this are never fast (none is in the dialect today) */
#define SIGNATURE_LEN 13
#define MAX_FILTERS 16

static uint8_t crc_extra[IDS];
static uint8_t known_ids[IDS / 8];
static uint8_t v1_max[256];

#define BIT(map, id) ((map)[(id) >> 3] & (1u << ((id) & 7)))

typedef struct {
    uint32_t msgid;
    uint32_t offset;                 /* in the payload */
    uint8_t values[32];              /* bitmap of the byte values that make a frame wanted */
} Filter;

/* What Python wants from one route: whole ids, and ids wanted only for some values of one payload byte. */
typedef struct {
    uint8_t wanted[IDS / 8];
    uint8_t filtered[IDS / 8];
    int n_filters;
    Filter filters[MAX_FILTERS];
} Wants;

typedef struct {
    PyObject_HEAD
    int fd;
    int all_up;                      /* Python wants every datagram (observers, signing key, rules, ...) */
    int has_peer;
    struct sockaddr_storage peer;
    int n_targets;
    int tfd[MAX_TARGETS];
    struct sockaddr_storage taddr[MAX_TARGETS];
    socklen_t tlen[MAX_TARGETS];
    Wants wants;
    int n, next;                     /* received datagrams in the batch, the next one to look at */
    double rx_s;
    struct mmsghdr msgs[BATCH];
    struct iovec iov[BATCH];
    struct sockaddr_storage addrs[BATCH];
    struct mmsghdr out[BATCH];
    /* calloc'd apart from the object: only the pages datagrams were written to count in the RSS */
    uint8_t (*bufs)[BUF_LEN];
} Route;

static inline uint16_t crc_acc(uint16_t crc, uint8_t b) {
    uint8_t t = b ^ (uint8_t)(crc & 0xff);
    t ^= (uint8_t)(t << 4);
    return (uint16_t)((crc >> 8) ^ ((uint16_t)t << 8) ^ ((uint16_t)t << 3) ^ (t >> 4));
}

static double monotonic_s(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);  /* time.monotonic() reads the same clock */
    return (double)ts.tv_sec + (double)ts.tv_nsec * 1e-9;
}

/* Whether a frame of filtered id msgid with this payload is wanted (its byte holds one of the values). */
static int filter_wants(const Wants *w, uint32_t msgid, const uint8_t *payload, uint8_t len) {
    for (int k = 0; k < w->n_filters; k++) {
        const Filter *f = &w->filters[k];
        if (f->msgid != msgid)
            continue;
        uint8_t v = f->offset < len ? payload[f->offset] : 0;  /* MAVLink 2 truncates trailing zero bytes */
        return BIT(f->values, v) != 0;
    }
    return 1;
}

/* Frames in d[0:n] if it is nothing but valid frames of known ids nobody wants, else -1. */
static int fast_frames(const Wants *w, const uint8_t *d, Py_ssize_t n, int *n_signed) {
    Py_ssize_t i = 0;
    int frames = 0, sgn = 0;
    if (n == 0)
        return -1;
    while (i < n) {
        uint32_t msgid;
        Py_ssize_t crc_at, end, payload;
        int is_signed = 0;
        if (d[i] == 0xFD) {
            if (n - i < 10)
                return -1;
            uint8_t incompat = d[i + 2];
            if (incompat > 1)
                return -1;  /* an incompatibility flag other than signing: bad_flags */
            msgid = (uint32_t)d[i + 7] | (uint32_t)d[i + 8] << 8 | (uint32_t)d[i + 9] << 16;
            payload = i + 10;
            crc_at = payload + d[i + 1];
            is_signed = incompat;
            end = crc_at + 2 + (incompat ? SIGNATURE_LEN : 0);
            if (end > n)
                return -1;
            if (incompat) {
                /* The CRC does not cover the signature; the splitter looks for a frame starting inside it. */
                for (Py_ssize_t j = crc_at + 2; j < end; j++)
                    if (d[j] == 0xFD || d[j] == 0xFE)
                        return -1;
                sgn++;
            }
        } else if (d[i] == 0xFE) {
            if (n - i < 6)
                return -1;
            msgid = d[i + 5];
            if (BIT(known_ids, msgid) && d[i + 1] > v1_max[msgid])
                return -1;  /* MAVLink 1 has no extensions: bad_length */
            payload = i + 6;
            crc_at = payload + d[i + 1];
            end = crc_at + 2;
            if (end > n)
                return -1;
        } else {
            return -1;
        }
        if (msgid >= IDS || !BIT(known_ids, msgid) || BIT(w->wanted, msgid))
            return -1;
        if (BIT(w->filtered, msgid) && (is_signed || filter_wants(w, msgid, d + payload, d[i + 1])))
            return -1;
        uint16_t crc = 0xFFFF;
        for (Py_ssize_t j = i + 1; j < crc_at; j++)
            crc = crc_acc(crc, d[j]);
        crc = crc_acc(crc, crc_extra[msgid]);
        if (crc != (uint16_t)(d[crc_at] | d[crc_at + 1] << 8))
            return -1;
        frames++;
        i = end;
    }
    *n_signed = sgn;
    return frames;
}

static int addr_equal(const struct sockaddr_storage *a, const struct sockaddr_storage *b) {
    if (a->ss_family != b->ss_family)
        return 0;
    if (a->ss_family == AF_INET) {
        const struct sockaddr_in *x = (const void *)a, *y = (const void *)b;
        return x->sin_port == y->sin_port && x->sin_addr.s_addr == y->sin_addr.s_addr;
    }
    if (a->ss_family == AF_INET6) {
        const struct sockaddr_in6 *x = (const void *)a, *y = (const void *)b;
        return x->sin6_port == y->sin6_port && x->sin6_scope_id == y->sin6_scope_id &&
               x->sin6_flowinfo == y->sin6_flowinfo && !memcmp(&x->sin6_addr, &y->sin6_addr, 16);
    }
    return 0;
}

/* (family, addr) as the socket module gives them -> a sockaddr; 0 on success, -1 with an exception set. */
static int parse_addr(int family, PyObject *addr, struct sockaddr_storage *out, socklen_t *len) {
    const char *host;
    unsigned int port, flow = 0, scope = 0;
    memset(out, 0, sizeof(*out));
    if (family == AF_INET) {
        struct sockaddr_in *s = (void *)out;
        if (!PyArg_ParseTuple(addr, "sI", &host, &port))
            return -1;
        s->sin_family = AF_INET;
        s->sin_port = htons((uint16_t)port);
        if (inet_pton(AF_INET, host, &s->sin_addr) != 1) {
            PyErr_Format(PyExc_ValueError, "not an IPv4 address: %s", host);
            return -1;
        }
        *len = sizeof(*s);
        return 0;
    }
    if (family == AF_INET6) {
        struct sockaddr_in6 *s = (void *)out;
        if (!PyArg_ParseTuple(addr, "sI|II", &host, &port, &flow, &scope))
            return -1;
        s->sin6_family = AF_INET6;
        s->sin6_port = htons((uint16_t)port);
        s->sin6_flowinfo = htonl(flow);
        s->sin6_scope_id = scope;
        if (inet_pton(AF_INET6, host, &s->sin6_addr) != 1) {
            PyErr_Format(PyExc_ValueError, "not an IPv6 address: %s", host);
            return -1;
        }
        *len = sizeof(*s);
        return 0;
    }
    PyErr_Format(PyExc_ValueError, "address family %d is not IPv4 or IPv6", family);
    return -1;
}

static PyObject *addr_tuple(const struct sockaddr_storage *a) {
    char host[INET6_ADDRSTRLEN];
    if (a->ss_family == AF_INET) {
        const struct sockaddr_in *s = (const void *)a;
        inet_ntop(AF_INET, &s->sin_addr, host, sizeof(host));
        return Py_BuildValue("(si)", host, ntohs(s->sin_port));
    }
    if (a->ss_family == AF_INET6) {
        const struct sockaddr_in6 *s = (const void *)a;
        inet_ntop(AF_INET6, &s->sin6_addr, host, sizeof(host));
        return Py_BuildValue("(siII)", host, ntohs(s->sin6_port), ntohl(s->sin6_flowinfo), s->sin6_scope_id);
    }
    Py_RETURN_NONE;
}

static int Route_init(Route *self, PyObject *args, PyObject *kw) {
    if (!PyArg_ParseTuple(args, "i", &self->fd))
        return -1;
    if (self->bufs == NULL) {
        self->bufs = calloc(BATCH, BUF_LEN);
        if (self->bufs == NULL) {
            PyErr_NoMemory();
            return -1;
        }
    }
    self->all_up = 1;
    self->has_peer = 0;
    self->n_targets = 0;
    self->n = self->next = 0;
    memset(&self->wants, 0, sizeof(self->wants));
    return 0;
}

/* wanted: an 8192-byte bitmap of whole ids; filters: [(msgid, payload offset, 32-byte bitmap of values)]. */
static int parse_wants(Wants *w, Py_buffer *wanted, PyObject *filters) {
    if (wanted->len != IDS / 8) {
        PyErr_Format(PyExc_ValueError, "wanted must be %d bytes", IDS / 8);
        return -1;
    }
    PyObject *seq = PySequence_Fast(filters, "filters must be a sequence");
    if (seq == NULL)
        return -1;
    Py_ssize_t nf = PySequence_Fast_GET_SIZE(seq);
    if (nf > MAX_FILTERS) {
        Py_DECREF(seq);
        PyErr_Format(PyExc_ValueError, "at most %d filters", MAX_FILTERS);
        return -1;
    }
    Wants fresh;
    memset(&fresh, 0, sizeof(fresh));
    memcpy(fresh.wanted, wanted->buf, IDS / 8);
    for (Py_ssize_t k = 0; k < nf; k++) {
        unsigned int msgid, offset;
        Py_buffer values;
        if (!PyArg_ParseTuple(PySequence_Fast_GET_ITEM(seq, k), "IIy*", &msgid, &offset, &values)) {
            Py_DECREF(seq);
            return -1;
        }
        int bad = values.len != 32 || msgid >= IDS || offset > 255;
        if (!bad)
            memcpy(fresh.filters[k].values, values.buf, 32);
        PyBuffer_Release(&values);
        if (bad) {
            Py_DECREF(seq);
            PyErr_Format(PyExc_ValueError, "a filter is (msgid < %d, offset < 256, 32-byte bitmap)", IDS);
            return -1;
        }
        fresh.filters[k].msgid = msgid;
        fresh.filters[k].offset = offset;
        fresh.filtered[msgid >> 3] |= (uint8_t)(1u << (msgid & 7));
    }
    Py_DECREF(seq);
    fresh.n_filters = (int)nf;
    memcpy(w, &fresh, sizeof(fresh));
    return 0;
}

/* configure(all_up, family, peer or None, [(fd, family, addr), ...], wanted: 8192-byte bitmap,
 *           filters: [(msgid, payload offset, 32-byte bitmap of values)]) */
static PyObject *Route_configure(Route *self, PyObject *args) {
    int all_up, family;
    PyObject *peer, *targets, *filters;
    Py_buffer wanted;
    if (!PyArg_ParseTuple(args, "piOOy*O", &all_up, &family, &peer, &targets, &wanted, &filters))
        return NULL;
    self->all_up = 1;  /* until the whole configuration is in */
    int rc = parse_wants(&self->wants, &wanted, filters);
    PyBuffer_Release(&wanted);
    if (rc < 0)
        return NULL;
    self->has_peer = 0;
    if (peer != Py_None) {
        socklen_t len;
        if (parse_addr(family, peer, &self->peer, &len) < 0)
            return NULL;
        self->has_peer = 1;
    }
    PyObject *seq = PySequence_Fast(targets, "targets must be a sequence");
    if (seq == NULL)
        return NULL;
    Py_ssize_t nt = PySequence_Fast_GET_SIZE(seq);
    if (nt > MAX_TARGETS) {
        Py_DECREF(seq);
        return PyErr_Format(PyExc_ValueError, "at most %d targets", MAX_TARGETS);
    }
    for (Py_ssize_t t = 0; t < nt; t++) {
        int fd, tfam;
        PyObject *taddr;
        if (!PyArg_ParseTuple(PySequence_Fast_GET_ITEM(seq, t), "iiO", &fd, &tfam, &taddr) ||
            parse_addr(tfam, taddr, &self->taddr[t], &self->tlen[t]) < 0) {
            Py_DECREF(seq);
            self->n_targets = 0;
            return NULL;
        }
        self->tfd[t] = fd;
    }
    Py_DECREF(seq);
    self->n_targets = (int)nt;
    /* No targets is Python's to allow: every target muted (nobody listens), the datagrams go nowhere. */
    self->all_up = all_up || !self->has_peer;
    Py_RETURN_NONE;
}

static int lat_bin(double s, Py_ssize_t nbins) {
    /* stats.LatencyHistogram: 1 us .. 100 s, 120 bins a decade, underflow and overflow bins. */
    if (!(s > 1e-6))
        return 0;
    if (s >= 100.0)
        return (int)nbins - 1;
    return 1 + (int)(log10(s / 1e-6) * 120);
}

/* Send bufs[lo:hi] to every target, in order. sent[t] counts what each took; err[t] is the last errno;
 * unsent[t] is where the kernel stopped taking datagrams (a full send buffer), else hi. */
static void send_run(Route *r, int lo, int hi, long *sent, int *err, int *unsent) {
    int cnt = hi - lo;
    for (int t = 0; t < r->n_targets; t++) {
        for (int k = 0; k < cnt; k++) {
            struct msghdr *h = &r->out[k].msg_hdr;
            memset(h, 0, sizeof(*h));
            h->msg_name = &r->taddr[t];
            h->msg_namelen = r->tlen[t];
            h->msg_iov = &r->iov[lo + k];
            h->msg_iovlen = 1;
        }
        int done = 0;
        unsent[t] = hi;
        while (done < cnt) {
#ifdef __linux__
            int rc = sendmmsg(r->tfd[t], r->out + done, (unsigned)(cnt - done), 0);
#else
            int rc = sendmsg(r->tfd[t], &r->out[done].msg_hdr, 0) < 0 ? -1 : 1;
#endif
            if (rc < 0) {
                if (errno == EINTR)
                    continue;
                if (errno == EAGAIN || errno == EWOULDBLOCK || errno == ENOBUFS) {
                    unsent[t] = lo + done;  /* the kernel takes no more now: Python queues the rest */
                    break;
                }
                err[t] = errno;  /* e.g. ECONNREFUSED: an ICMP error reported on this send; it is consumed */
                done++;
                continue;
            }
            sent[t] += rc;
            done += rc;
        }
    }
}

/* drain(latency_counts) -> None (nothing to read), an int errno (the socket reported an error), or
 * (datagrams, frames, bytes, signed, rx_s, latency_s, sent, errors, unsent, up, more):
 *   the fast datagrams sent (their frames, bytes, signed frames), when the batch was received, how long
 *   they were in the proxy, per target the datagrams it took, its errno (0: none) and None or the list of
 *   datagrams its full send buffer did not take (to be queued, in order); up: None or
 *   (data or None when longer than MAX_DATAGRAM, addr, rx_s, size), the datagram Python must handle next;
 *   more: datagrams of this batch still wait, call again. latency_counts: the link's latency histogram
 *   (array 'q'), where each fast datagram's time in the proxy is counted. */
static PyObject *Route_drain(Route *self, PyObject *args) {
    Py_buffer hist;
    if (self->bufs == NULL)
        return PyErr_Format(PyExc_RuntimeError, "Route not initialised");
    if (!PyArg_ParseTuple(args, "w*", &hist))
        return NULL;
    Py_ssize_t nbins = hist.len / (Py_ssize_t)sizeof(long long);
    long long *counts = hist.buf;
    if (self->next >= self->n) {
        for (int i = 0; i < BATCH; i++) {
            self->iov[i].iov_base = self->bufs[i];
            self->iov[i].iov_len = BUF_LEN;
            struct msghdr *h = &self->msgs[i].msg_hdr;
            memset(h, 0, sizeof(*h));
            h->msg_name = &self->addrs[i];
            h->msg_namelen = sizeof(self->addrs[i]);
            h->msg_iov = &self->iov[i];
            h->msg_iovlen = 1;
        }
        int got;
        do {
#ifdef __linux__
            got = recvmmsg(self->fd, self->msgs, BATCH, MSG_TRUNC, NULL);
#else
            ssize_t one = recvmsg(self->fd, &self->msgs[0].msg_hdr, MSG_TRUNC);
            if (one >= 0)
                self->msgs[0].msg_len = (unsigned)one;
            got = one < 0 ? -1 : 1;
#endif
        } while (got < 0 && errno == EINTR);
        if (got < 0) {
            int e = errno;
            PyBuffer_Release(&hist);
            if (e == EAGAIN || e == EWOULDBLOCK)
                Py_RETURN_NONE;
            return PyLong_FromLong(e);
        }
        self->n = got;
        self->next = 0;
        self->rx_s = monotonic_s();
    }
    long dgrams = 0, frames = 0, bytes = 0, sgn = 0;
    long sent[MAX_TARGETS] = {0};
    int err[MAX_TARGETS] = {0}, unsent[MAX_TARGETS];
    int lo = self->next, i = lo;
    PyObject *up = NULL;
    for (; i < self->n; i++) {
        struct msghdr *h = &self->msgs[i].msg_hdr;
        Py_ssize_t len = self->msgs[i].msg_len;
        int s = 0, f = -1;
        if (!self->all_up && !(h->msg_flags & MSG_TRUNC) && len <= MAX_DATAGRAM &&
            addr_equal(&self->addrs[i], &self->peer))
            f = fast_frames(&self->wants, self->bufs[i], len, &s);
        if (f < 0) {
            /* Up to Python, after the fast ones before it. */
            PyObject *data;
            if ((h->msg_flags & MSG_TRUNC) || len > MAX_DATAGRAM) {
                data = Py_None;
                Py_INCREF(data);
            } else {
                data = PyBytes_FromStringAndSize((const char *)self->bufs[i], len);
            }
            PyObject *addr = addr_tuple(&self->addrs[i]);
            if (data == NULL || addr == NULL) {
                Py_XDECREF(data);
                Py_XDECREF(addr);
                PyBuffer_Release(&hist);
                return NULL;
            }
            up = Py_BuildValue("(NNdn)", data, addr, self->rx_s, len);
            if (up == NULL) {
                PyBuffer_Release(&hist);
                return NULL;
            }
            break;
        }
        self->iov[i].iov_len = (size_t)len;
        dgrams++;
        frames += f;
        bytes += len;
        sgn += s;
    }
    double lat = 0.0;
    for (int t = 0; t < self->n_targets; t++)
        unsent[t] = i;
    if (i > lo)
        send_run(self, lo, i, sent, err, unsent);
    /* What a target's full send buffer did not take, as bytes for Python's queue (asyncio's transports queue too). */
    PyObject *tover = PyTuple_New(self->n_targets);
    if (tover == NULL) {
        Py_XDECREF(up);
        PyBuffer_Release(&hist);
        return NULL;
    }
    for (int t = 0; t < self->n_targets; t++) {
        PyObject *rest = Py_None;
        if (unsent[t] < i) {
            rest = PyList_New(0);
            for (int k = unsent[t]; rest != NULL && k < i; k++) {
                PyObject *b = PyBytes_FromStringAndSize((const char *)self->bufs[k], (Py_ssize_t)self->iov[k].iov_len);
                if (b == NULL || PyList_Append(rest, b) < 0) {
                    Py_XDECREF(b);
                    Py_CLEAR(rest);
                    break;
                }
                Py_DECREF(b);
            }
            if (rest == NULL) {
                Py_DECREF(tover);
                Py_XDECREF(up);
                PyBuffer_Release(&hist);
                return NULL;
            }
        } else {
            Py_INCREF(rest);
        }
        PyTuple_SET_ITEM(tover, t, rest);
    }
    if (i > lo) {
        for (int k = lo; k < i; k++)
            self->iov[k].iov_len = BUF_LEN;
        lat = monotonic_s() - self->rx_s;
        if (nbins > 2)
            counts[lat_bin(lat, nbins)] += i - lo;
    }
    self->next = up != NULL ? i + 1 : i;
    PyBuffer_Release(&hist);
    PyObject *tsent = PyTuple_New(self->n_targets), *terr = PyTuple_New(self->n_targets);
    if (tsent == NULL || terr == NULL) {
        Py_XDECREF(tsent);
        Py_XDECREF(terr);
        Py_XDECREF(tover);
        Py_XDECREF(up);
        return NULL;
    }
    for (int t = 0; t < self->n_targets; t++) {
        PyTuple_SET_ITEM(tsent, t, PyLong_FromLong(sent[t]));
        PyTuple_SET_ITEM(terr, t, PyLong_FromLong(err[t]));
    }
    if (up == NULL) {
        up = Py_None;
        Py_INCREF(up);
    }
    return Py_BuildValue("(llllddNNNNO)", dgrams, frames, bytes, sgn, self->rx_s, lat, tsent, terr, tover, up,
                         self->next < self->n ? Py_True : Py_False);
}

/* check(data, wanted[, filters]) -> frames or -1: the fast path's verdict on one datagram, for tests. */
static PyObject *fp_check(PyObject *mod, PyObject *args) {
    Py_buffer data, wanted;
    PyObject *filters = NULL;
    if (!PyArg_ParseTuple(args, "y*y*|O", &data, &wanted, &filters))
        return NULL;
    Wants *w = PyMem_Malloc(sizeof(Wants));
    if (w == NULL) {
        PyBuffer_Release(&data);
        PyBuffer_Release(&wanted);
        return PyErr_NoMemory();
    }
    PyObject *none = NULL;
    if (filters == NULL)
        filters = none = PyTuple_New(0);
    int rc = filters == NULL ? -1 : parse_wants(w, &wanted, filters);
    Py_XDECREF(none);
    int s = 0, f = -1;
    if (rc == 0)
        f = fast_frames(w, data.buf, data.len, &s);
    PyMem_Free(w);
    PyBuffer_Release(&data);
    PyBuffer_Release(&wanted);
    if (rc < 0)
        return NULL;
    return PyLong_FromLong(f);
}

/* set_dialect(crc_extra: 65536 bytes, known: 8192-byte bitmap, v1_max: 256 bytes) */
static PyObject *fp_set_dialect(PyObject *mod, PyObject *args) {
    Py_buffer ce, kn, vm;
    if (!PyArg_ParseTuple(args, "y*y*y*", &ce, &kn, &vm))
        return NULL;
    if (ce.len != IDS || kn.len != IDS / 8 || vm.len != 256) {
        PyBuffer_Release(&ce);
        PyBuffer_Release(&kn);
        PyBuffer_Release(&vm);
        return PyErr_Format(PyExc_ValueError, "tables must be %d, %d and 256 bytes", IDS, IDS / 8);
    }
    memcpy(crc_extra, ce.buf, IDS);
    memcpy(known_ids, kn.buf, IDS / 8);
    memcpy(v1_max, vm.buf, 256);
    PyBuffer_Release(&ce);
    PyBuffer_Release(&kn);
    PyBuffer_Release(&vm);
    Py_RETURN_NONE;
}

static void Route_dealloc(Route *self) {
    free(self->bufs);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

static PyMethodDef Route_methods[] = {
    {"configure", (PyCFunction)Route_configure, METH_VARARGS, "Set the peer, the targets and the wanted ids."},
    {"drain", (PyCFunction)Route_drain, METH_VARARGS, "Receive, forward what nobody wants, return the next up."},
    {NULL, NULL, 0, NULL},
};

static PyTypeObject RouteType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "mitm_proxy.net._fastpath.Route",
    .tp_basicsize = sizeof(Route),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_doc = "One receiving socket's fast path.",
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Route_init,
    .tp_dealloc = (destructor)Route_dealloc,
    .tp_methods = Route_methods,
};

static PyMethodDef module_methods[] = {
    {"set_dialect", fp_set_dialect, METH_VARARGS, "Load the CRC_EXTRA, known-id and MAVLink 1 length tables."},
    {"check", fp_check, METH_VARARGS, "Frames in a datagram the fast path would forward, or -1."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef moduledef = {
    PyModuleDef_HEAD_INIT, "_fastpath", "The proxy's compiled fast path.", -1, module_methods,
};

PyMODINIT_FUNC PyInit__fastpath(void) {
    if (PyType_Ready(&RouteType) < 0)
        return NULL;
    PyObject *m = PyModule_Create(&moduledef);
    if (m == NULL)
        return NULL;
    Py_INCREF(&RouteType);
    if (PyModule_AddObject(m, "Route", (PyObject *)&RouteType) < 0) {
        Py_DECREF(&RouteType);
        Py_DECREF(m);
        return NULL;
    }
    PyModule_AddIntConstant(m, "BATCH", BATCH);
    PyModule_AddIntConstant(m, "IDS", IDS);
    PyModule_AddIntConstant(m, "MAX_FILTERS", MAX_FILTERS);
    return m;
}
