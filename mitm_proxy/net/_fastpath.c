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
 * A wanted frame may still be answered here from the route's rewrite memory (a megaflow cache, as Open
 * vSwitch's datapath keeps): after Python rewrote a frame of an id it allows (the stages' memo_fields,
 * mitm_proxy/core/pipeline.py), learn() keeps "a frame of this msgid, version, sysid and compid whose
 * payload, less one span (its time field), is exactly this, leaves with these payload bytes changed",
 * until a monotonic time the stage gave. A later frame with the same key, valid and unsigned, arriving
 * before then, is rewritten here the way codec.encode re-packs (MAVLink 2: the patched payload with its
 * trailing zeros cut, at least one byte kept; MAVLink 1: the same length), with a fresh CRC, and sent in
 * its datagram; anything else goes up. learn() only keeps a rewrite it reproduces byte for byte.
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
#define MAX_MEMO_IDS 16              /* ids the rewrite memory may answer for */
#define MEMO_SLOTS 1024              /* entries per route (a power of two) */
#define MEMO_PROBE 8                 /* slots looked at per key */
#define MEMO_PATCH 32                /* payload bytes one remembered rewrite may change */
#define MAX_PAYLOAD 255
#define MAX_HITS 64                  /* remembered rewrites in one datagram; more go up */

static uint8_t crc_extra[IDS];
static uint8_t known_ids[IDS / 8];
static uint8_t v1_max[256];

#define BIT(map, id) ((map)[(id) >> 3] & (1u << ((id) & 7)))

typedef struct {
    uint32_t msgid;
    uint32_t offset;                 /* in the payload */
    uint8_t values[32];              /* bitmap of the byte values that make a frame wanted */
} Filter;

typedef struct {
    uint32_t msgid;
    uint32_t skip_off, skip_len;     /* the payload span left out of the key (the time field), or 0, 0 */
} MemoSpec;

/* What Python wants from one route: whole ids, ids wanted only for some values of one payload byte, and
 * the wanted ids whose rewrites the memory may repeat. */
typedef struct {
    uint8_t wanted[IDS / 8];
    uint8_t filtered[IDS / 8];
    int n_filters;
    Filter filters[MAX_FILTERS];
    uint8_t memo_ids[IDS / 8];
    int n_memo;
    MemoSpec memo[MAX_MEMO_IDS];
} Wants;

/* One remembered rewrite; hash 0 marks an empty slot. */
typedef struct {
    uint64_t hash;
    double until_s;                  /* monotonic: not used for frames received at or after it */
    uint32_t msgid;
    uint8_t version, sysid, compid, key_len;
    uint8_t n_patch;
    uint8_t repack;                  /* Python re-packed the frame (else it left as it came) */
    uint8_t rewritten;               /* ... and counted a rewrite (stats.rewritten) */
    uint8_t key[MAX_PAYLOAD];
    uint8_t patch_off[MEMO_PATCH];
    uint8_t patch_val[MEMO_PATCH];
} Memo;

/* A remembered rewrite found for a frame of a datagram: where the frame is and what to do with it. */
typedef struct {
    Py_ssize_t at, end;
    const Memo *memo;
} Hit;

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
    Memo *memos;                     /* MEMO_SLOTS, calloc'd at the first learn() */
    uint8_t obuf[BUF_LEN + MAX_PAYLOAD];  /* a datagram with remembered rewrites, built before it is sent */
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

/* -- the rewrite memory --------------------------------------------------------------------------- */

static const MemoSpec *memo_spec(const Wants *w, uint32_t msgid) {
    for (int k = 0; k < w->n_memo; k++)
        if (w->memo[k].msgid == msgid)
            return &w->memo[k];
    return NULL;
}

/* The key of a payload: its bytes with the spec's span zeroed and trailing zeros cut (a MAVLink 2 payload
 * decodes as if padded with zeros, so a truncated and a full one with the same values share a key). */
static int memo_key(const MemoSpec *spec, const uint8_t *payload, int len, uint8_t *key) {
    memcpy(key, payload, (size_t)len);
    if (spec->skip_len) {
        for (uint32_t j = spec->skip_off; j < spec->skip_off + spec->skip_len && j < (uint32_t)len; j++)
            key[j] = 0;
    }
    while (len > 0 && key[len - 1] == 0)
        len--;
    return len;
}

static uint64_t memo_hash(uint32_t msgid, uint8_t version, uint8_t sysid, uint8_t compid, const uint8_t *key,
                          int len) {
    uint64_t h = 1469598103934665603ULL;  /* FNV-1a */
    uint8_t head[7] = {(uint8_t)msgid, (uint8_t)(msgid >> 8), (uint8_t)(msgid >> 16), version, sysid, compid,
                       (uint8_t)len};
    for (int j = 0; j < 7; j++)
        h = (h ^ head[j]) * 1099511628211ULL;
    for (int j = 0; j < len; j++)
        h = (h ^ key[j]) * 1099511628211ULL;
    return h ? h : 1;
}

/* The slot holding this key, or (insert) the slot to write it to; find: NULL when it is not there. */
static Memo *memo_slot(Memo *memos, uint64_t h, uint32_t msgid, uint8_t version, uint8_t sysid, uint8_t compid,
                       const uint8_t *key, int len, int insert) {
    for (int k = 0; k < MEMO_PROBE; k++) {
        Memo *m = &memos[(h + (uint64_t)k) & (MEMO_SLOTS - 1)];
        if (m->hash == 0)
            return insert ? m : NULL;
        if (m->hash == h && m->msgid == msgid && m->version == version && m->sysid == sysid &&
            m->compid == compid && m->key_len == len && !memcmp(m->key, key, (size_t)len))
            return m;
    }
    return insert ? &memos[h & (MEMO_SLOTS - 1)] : NULL;  /* a full neighbourhood: the oldest guess goes */
}

/* The remembered rewrite for the frame at f (valid, unsigned), or NULL. */
static const Memo *memo_find(const Memo *memos, const Wants *w, uint32_t msgid, const uint8_t *f) {
    const MemoSpec *spec = memo_spec(w, msgid);
    if (memos == NULL || spec == NULL)
        return NULL;
    int v2 = f[0] == 0xFD;
    uint8_t key[MAX_PAYLOAD];
    int len = memo_key(spec, f + (v2 ? 10 : 6), f[1], key);
    uint8_t version = v2 ? 2 : 1, sysid = f[v2 ? 5 : 3], compid = f[v2 ? 6 : 4];
    uint64_t h = memo_hash(msgid, version, sysid, compid, key, len);
    return memo_slot((Memo *)memos, h, msgid, version, sysid, compid, key, len, 0);
}

/* The frame f (flen bytes, unsigned) as the remembered rewrite m leaves it, written to out; its length. */
static Py_ssize_t memo_apply(const Memo *m, const uint8_t *f, Py_ssize_t flen, uint8_t *out) {
    if (!m->repack) {
        memcpy(out, f, (size_t)flen);
        return flen;
    }
    int v2 = f[0] == 0xFD, hdr = v2 ? 10 : 6, len = f[1];
    uint8_t payload[MAX_PAYLOAD];
    memset(payload, 0, sizeof(payload));
    memcpy(payload, f + hdr, (size_t)len);
    for (int k = 0; k < m->n_patch; k++)
        payload[m->patch_off[k]] = m->patch_val[k];
    if (v2) {  /* codec.encode: trailing zeros cut, at least one byte kept */
        len = MAX_PAYLOAD;
        while (len > 1 && payload[len - 1] == 0)
            len--;
    }
    memcpy(out, f, (size_t)hdr);
    out[1] = (uint8_t)len;
    memcpy(out + hdr, payload, (size_t)len);
    uint16_t crc = 0xFFFF;
    for (int j = 1; j < hdr + len; j++)
        crc = crc_acc(crc, out[j]);
    crc = crc_acc(crc, crc_extra[m->msgid]);
    out[hdr + len] = (uint8_t)(crc & 0xff);
    out[hdr + len + 1] = (uint8_t)(crc >> 8);
    return hdr + len + 2;
}

/* Frames in d[0:n] if it is nothing but valid frames of known ids that nobody wants or that the memory
 * answers (memos may be NULL: none; each answered frame is noted in hits), else -1. */
static int fast_frames(const Wants *w, const Memo *memos, double rx_s, const uint8_t *d, Py_ssize_t n,
                       int *n_signed, Hit *hits, int *n_hits) {
    Py_ssize_t i = 0;
    int frames = 0, sgn = 0, nh = 0;
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
        if (msgid >= IDS || !BIT(known_ids, msgid))
            return -1;
        int wanted = BIT(w->wanted, msgid) ||
                     (BIT(w->filtered, msgid) && (is_signed || filter_wants(w, msgid, d + payload, d[i + 1])));
        if (wanted && (memos == NULL || is_signed || !BIT(w->memo_ids, msgid) || nh >= MAX_HITS))
            return -1;
        uint16_t crc = 0xFFFF;
        for (Py_ssize_t j = i + 1; j < crc_at; j++)
            crc = crc_acc(crc, d[j]);
        crc = crc_acc(crc, crc_extra[msgid]);
        if (crc != (uint16_t)(d[crc_at] | d[crc_at + 1] << 8))
            return -1;
        if (wanted) {
            const Memo *m = memo_find(memos, w, msgid, d + i);
            if (m == NULL || !(rx_s < m->until_s))
                return -1;
            hits[nh].at = i;
            hits[nh].end = end;
            hits[nh].memo = m;
            nh++;
        }
        frames++;
        i = end;
    }
    *n_signed = sgn;
    *n_hits = nh;
    return frames;
}

/* d[0:n] with the hits' frames rewritten, into out (cap bytes); its length, or -1 when it would outgrow a
 * datagram (it then goes up, as it came). *rewritten: how many of them Python counted as rewrites. */
static Py_ssize_t rewrite_datagram(const uint8_t *d, Py_ssize_t n, const Hit *hits, int nh, uint8_t *out,
                                   Py_ssize_t cap, long *rewritten) {
    Py_ssize_t o = 0, at = 0;
    long rw = 0;
    for (int k = 0; k < nh; k++) {
        Py_ssize_t keep = hits[k].at - at;
        if (o + keep + 10 + MAX_PAYLOAD + 2 > cap)
            return -1;
        memcpy(out + o, d + at, (size_t)keep);
        o += keep;
        o += memo_apply(hits[k].memo, d + hits[k].at, hits[k].end - hits[k].at, out + o);
        rw += hits[k].memo->rewritten;
        at = hits[k].end;
    }
    if (o + (n - at) > cap)
        return -1;
    memcpy(out + o, d + at, (size_t)(n - at));
    o += n - at;
    if (o > MAX_DATAGRAM)
        return -1;
    *rewritten = rw;
    return o;
}

/* What the route does with the datagram d[0:n] from its peer, received at rx_s: -1 when it goes up, else its
 * frames, sent as they came (*n_hits 0) or, rewritten from the memory, as r->obuf[0:*out_len]. */
static int route_datagram(Route *r, const uint8_t *d, Py_ssize_t n, double rx_s, int *n_signed, int *n_hits,
                          Py_ssize_t *out_len, long *rewritten) {
    Hit hits[MAX_HITS];
    *n_hits = 0;
    *rewritten = 0;
    *out_len = n;
    if (r->all_up || n > MAX_DATAGRAM)
        return -1;
    int f = fast_frames(&r->wants, r->memos, rx_s, d, n, n_signed, hits, n_hits);
    if (f >= 0 && *n_hits > 0) {
        *out_len = rewrite_datagram(d, n, hits, *n_hits, r->obuf, (Py_ssize_t)sizeof(r->obuf), rewritten);
        if (*out_len < 0)
            return -1;
    }
    return f;
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
    if (self->memos != NULL)
        memset(self->memos, 0, MEMO_SLOTS * sizeof(Memo));
    return 0;
}

/* wanted: an 8192-byte bitmap of whole ids; filters: [(msgid, payload offset, 32-byte bitmap of values)];
 * memo: NULL or [(msgid, offset, length)]: the ids whose rewrites the memory may repeat, each with the payload
 * span its key leaves out. */
static int parse_wants(Wants *w, Py_buffer *wanted, PyObject *filters, PyObject *memo) {
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
    if (memo != NULL) {
        seq = PySequence_Fast(memo, "memo must be a sequence");
        if (seq == NULL)
            return -1;
        Py_ssize_t nm = PySequence_Fast_GET_SIZE(seq);
        if (nm > MAX_MEMO_IDS) {
            Py_DECREF(seq);
            PyErr_Format(PyExc_ValueError, "at most %d memo ids", MAX_MEMO_IDS);
            return -1;
        }
        for (Py_ssize_t k = 0; k < nm; k++) {
            unsigned int msgid, off, len;
            if (!PyArg_ParseTuple(PySequence_Fast_GET_ITEM(seq, k), "III", &msgid, &off, &len)) {
                Py_DECREF(seq);
                return -1;
            }
            if (msgid >= IDS || off > MAX_PAYLOAD || len > MAX_PAYLOAD) {
                Py_DECREF(seq);
                PyErr_Format(PyExc_ValueError, "a memo id is (msgid < %d, offset, length <= 255)", IDS);
                return -1;
            }
            fresh.memo[k].msgid = msgid;
            fresh.memo[k].skip_off = off;
            fresh.memo[k].skip_len = len;
            fresh.memo_ids[msgid >> 3] |= (uint8_t)(1u << (msgid & 7));
        }
        Py_DECREF(seq);
        fresh.n_memo = (int)nm;
    }
    memcpy(w, &fresh, sizeof(fresh));
    return 0;
}

/* configure(all_up, family, peer or None, [(fd, family, addr), ...], wanted: 8192-byte bitmap,
 *           filters: [(msgid, payload offset, 32-byte bitmap of values)], memo: [(msgid, offset, length)]) */
static PyObject *Route_configure(Route *self, PyObject *args) {
    int all_up, family;
    PyObject *peer, *targets, *filters, *memo = NULL;
    Py_buffer wanted;
    if (!PyArg_ParseTuple(args, "piOOy*O|O", &all_up, &family, &peer, &targets, &wanted, &filters, &memo))
        return NULL;
    self->all_up = 1;  /* until the whole configuration is in */
    int rc = parse_wants(&self->wants, &wanted, filters, memo);
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
    long dgrams = 0, frames = 0, bytes = 0, bytes_out = 0, sgn = 0, rewritten = 0;
    long sent[MAX_TARGETS] = {0};
    int err[MAX_TARGETS] = {0}, unsent[MAX_TARGETS];
    int lo = self->next, i = lo;
    PyObject *up = NULL;
    for (; i < self->n; i++) {
        struct msghdr *h = &self->msgs[i].msg_hdr;
        Py_ssize_t len = self->msgs[i].msg_len;
        int s = 0, f = -1, nh = 0;
        Py_ssize_t out_len = len;
        long rw = 0;
        if (!(h->msg_flags & MSG_TRUNC) && addr_equal(&self->addrs[i], &self->peer))
            f = route_datagram(self, self->bufs[i], len, self->rx_s, &s, &nh, &out_len, &rw);
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
        if (nh > 0)
            memcpy(self->bufs[i], self->obuf, (size_t)out_len);
        self->iov[i].iov_len = (size_t)out_len;
        dgrams++;
        frames += f;
        bytes += len;
        bytes_out += out_len;
        rewritten += rw;
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
    return Py_BuildValue("(llllllddNNNNO)", dgrams, frames, bytes, bytes_out, sgn, rewritten, self->rx_s, lat, tsent,
                         terr, tover, up, self->next < self->n ? Py_True : Py_False);
}

/* learn(frame, out, until_s, rewritten) -> bool: remember that ``frame`` (one whole unsigned frame of a memo
 * id) left as ``out`` (Python's bytes for it: the same, or re-packed), for frames with its key received before
 * until_s (monotonic); rewritten: Python counted it as a rewrite. False when it is not one this route can
 * repeat byte for byte (not a memo id, a signed frame, more than MEMO_PATCH bytes changed, ...). */
static PyObject *Route_learn(Route *self, PyObject *args) {
    Py_buffer raw, out;
    double until_s;
    int counted;
    if (!PyArg_ParseTuple(args, "y*y*dp", &raw, &out, &until_s, &counted))
        return NULL;
    const uint8_t *f = raw.buf, *o = out.buf;
    Py_ssize_t n = raw.len;
    int ok = 0;
    Memo m;
    memset(&m, 0, sizeof(m));
    const MemoSpec *spec = NULL;
    int v2 = n >= 8 && f[0] == 0xFD, hdr = v2 ? 10 : 6;
    if (n >= 8 && (v2 || f[0] == 0xFE) && n == hdr + f[1] + 2 && !(v2 && f[2] != 0)) {
        m.msgid = v2 ? ((uint32_t)f[7] | (uint32_t)f[8] << 8 | (uint32_t)f[9] << 16) : f[5];
        if (m.msgid < IDS && BIT(self->wants.memo_ids, m.msgid))
            spec = memo_spec(&self->wants, m.msgid);
    }
    if (spec != NULL) {
        m.version = v2 ? 2 : 1;
        m.sysid = f[v2 ? 5 : 3];
        m.compid = f[v2 ? 6 : 4];
        m.until_s = until_s;
        m.rewritten = counted ? 1 : 0;
        m.key_len = (uint8_t)memo_key(spec, f + hdr, f[1], m.key);
        if (out.len == n && !memcmp(o, f, (size_t)n)) {
            ok = 1;  /* it left as it came */
        } else if (out.len >= hdr + 2 && o[0] == f[0] && out.len == hdr + o[1] + 2) {
            uint8_t was[MAX_PAYLOAD], now[MAX_PAYLOAD];
            memset(was, 0, sizeof(was));
            memset(now, 0, sizeof(now));
            memcpy(was, f + hdr, f[1]);
            memcpy(now, o + hdr, o[1]);
            ok = 1;
            for (int j = 0; j < MAX_PAYLOAD && ok; j++) {
                if (was[j] == now[j])
                    continue;
                if (m.n_patch == MEMO_PATCH || (!v2 && j >= f[1])) {
                    ok = 0;
                    break;
                }
                m.patch_off[m.n_patch] = (uint8_t)j;
                m.patch_val[m.n_patch] = now[j];
                m.n_patch++;
            }
            m.repack = 1;
            if (ok) {  /* kept only if repeating it gives Python's bytes exactly */
                uint8_t again[10 + MAX_PAYLOAD + 2];
                Py_ssize_t len = memo_apply(&m, f, n, again);
                ok = len == out.len && !memcmp(again, o, (size_t)len);
            }
        }
    }
    PyBuffer_Release(&raw);
    PyBuffer_Release(&out);
    if (!ok)
        Py_RETURN_FALSE;
    if (self->memos == NULL) {
        self->memos = calloc(MEMO_SLOTS, sizeof(Memo));
        if (self->memos == NULL)
            return PyErr_NoMemory();
    }
    m.hash = memo_hash(m.msgid, m.version, m.sysid, m.compid, m.key, m.key_len);
    *memo_slot(self->memos, m.hash, m.msgid, m.version, m.sysid, m.compid, m.key, m.key_len, 1) = m;
    Py_RETURN_TRUE;
}

/* forget(): drop every remembered rewrite (a new profile, a restarted clock). */
static PyObject *Route_forget(Route *self, PyObject *noargs) {
    if (self->memos != NULL)
        memset(self->memos, 0, MEMO_SLOTS * sizeof(Memo));
    Py_RETURN_NONE;
}

/* verdict(data, rx_s) -> None (it goes up) or (bytes sent, frames rewritten): what drain() would do with this
 * datagram from the peer, received at rx_s, under the route's configuration and memory; for tests. */
static PyObject *Route_verdict(Route *self, PyObject *args) {
    Py_buffer data;
    double rx_s;
    if (!PyArg_ParseTuple(args, "y*d", &data, &rx_s))
        return NULL;
    int s = 0, nh = 0;
    long rw = 0;
    Py_ssize_t len;
    int f = route_datagram(self, data.buf, data.len, rx_s, &s, &nh, &len, &rw);
    PyObject *res = NULL;
    if (f < 0)
        res = Py_None, Py_INCREF(res);
    else
        res = Py_BuildValue("(y#l)", nh > 0 ? (const char *)self->obuf : (const char *)data.buf, len, rw);
    PyBuffer_Release(&data);
    return res;
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
    int rc = filters == NULL ? -1 : parse_wants(w, &wanted, filters, NULL);
    Py_XDECREF(none);
    int s = 0, f = -1, nh = 0;
    if (rc == 0)
        f = fast_frames(w, NULL, 0.0, data.buf, data.len, &s, NULL, &nh);
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
    free(self->memos);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

static PyMethodDef Route_methods[] = {
    {"configure", (PyCFunction)Route_configure, METH_VARARGS, "Set the peer, the targets and the wanted ids."},
    {"drain", (PyCFunction)Route_drain, METH_VARARGS, "Receive, forward what nobody wants, return the next up."},
    {"learn", (PyCFunction)Route_learn, METH_VARARGS, "Remember how Python rewrote one frame, to repeat it."},
    {"forget", (PyCFunction)Route_forget, METH_NOARGS, "Drop every remembered rewrite."},
    {"verdict", (PyCFunction)Route_verdict, METH_VARARGS, "What drain() would send for one datagram (tests)."},
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
    PyModule_AddIntConstant(m, "MAX_MEMO_IDS", MAX_MEMO_IDS);
    PyModule_AddIntConstant(m, "MEMO_SLOTS", MEMO_SLOTS);
    PyModule_AddIntConstant(m, "MEMO_PATCH", MEMO_PATCH);
    return m;
}
