#include "protocol/msg.h"

#include <math.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/base/frames.h"
#include "common/base/version.h"

const char *proto_build_id(void)
{
    return pt_build_id();
}

const char *proto_msg_type_name(uint32_t type)
{
    switch (type) {
    case PROTO_MSG_HELLO:
        return "HELLO";
    case PROTO_MSG_CHALLENGE:
        return "CHALLENGE";
    case PROTO_MSG_AUTH:
        return "AUTH";
    case PROTO_MSG_WELCOME:
        return "WELCOME";
    case PROTO_MSG_ERROR:
        return "ERROR";
    case PROTO_MSG_WORK_REQUEST:
        return "WORK_REQUEST";
    case PROTO_MSG_TASK:
        return "TASK";
    case PROTO_MSG_SCENE_GET:
        return "SCENE_GET";
    case PROTO_MSG_SCENE_CHUNK:
        return "SCENE_CHUNK";
    case PROTO_MSG_RESULT:
        return "RESULT";
    case PROTO_MSG_HEARTBEAT:
        return "HEARTBEAT";
    case PROTO_MSG_JOB_END:
        return "JOB_END";
    case PROTO_MSG_GUIDE_GET:
        return "GUIDE_GET";
    case PROTO_MSG_GUIDE_CHUNK:
        return "GUIDE_CHUNK";
    case PROTO_MSG_DENOISE_TASK:
        return "DENOISE_TASK";
    case PROTO_MSG_DENOISE_GET:
        return "DENOISE_GET";
    case PROTO_MSG_DENOISE_CHUNK:
        return "DENOISE_CHUNK";
    case PROTO_MSG_DENOISE_RESULT:
        return "DENOISE_RESULT";
    case PROTO_MSG_SUBMIT:
        return "SUBMIT";
    case PROTO_MSG_LIST:
        return "LIST";
    case PROTO_MSG_STATUS:
        return "STATUS";
    case PROTO_MSG_WATCH:
        return "WATCH";
    case PROTO_MSG_CANCEL:
        return "CANCEL";
    case PROTO_MSG_FETCH:
        return "FETCH";
    case PROTO_MSG_UPLOAD:
        return "UPLOAD";
    case PROTO_MSG_FETCH_FRAME:
        return "FETCH_FRAME";
    case PROTO_MSG_SUBMITTED:
        return "SUBMITTED";
    case PROTO_MSG_JOB_LIST:
        return "JOB_LIST";
    case PROTO_MSG_JOB_INFO:
        return "JOB_INFO";
    case PROTO_MSG_IMAGE:
        return "IMAGE";
    }
    return "unknown";
}

const char *proto_job_state_name(uint32_t state)
{
    switch (state) {
    case PROTO_JOB_QUEUED:
        return "queued";
    case PROTO_JOB_RUNNING:
        return "running";
    case PROTO_JOB_DONE:
        return "done";
    case PROTO_JOB_CANCELLED:
        return "cancelled";
    case PROTO_JOB_FAILED:
        return "failed";
    }
    return "unknown";
}

int proto_msg_type_known(uint32_t type)
{
    return strcmp(proto_msg_type_name(type), "unknown") != 0;
}

int proto_msg_type_preauth(uint32_t type)
{
    return type >= PROTO_MSG_HELLO && type <= PROTO_MSG_ERROR;
}

/* ---- shared pieces ---- */

/* Encoders check a string before writing anything, so a refused message
 * leaves the writer as it was. */
static int str_fits(const char *s, size_t cap)
{
    return strnlen(s, cap + 1) <= cap;
}

/* Ends an encoder: on a writer failure, cuts the writer back to where the
 * message started, so no partial message is left in it. */
static pt_status w_done(proto_writer *w, size_t start, const char *what, pt_error *err)
{
    pt_status st = proto_writer_status(w);
    if (st != PT_OK) {
        proto_writer_truncate(w, start);
        return pt_error_set(err, st, "%s: %s", what, pt_status_str(st));
    }
    return PT_OK;
}

/* Shape of a tile: non-empty, ordered, within the per-task cap. NULL when fine. */
static const char *rect_problem(pt_rect t)
{
    if (t.x0 >= t.x1)
        return "tile x0 >= x1";
    if (t.y0 >= t.y1)
        return "tile y0 >= y1";
    if ((uint64_t)(t.x1 - t.x0) * (t.y1 - t.y0) > PROTO_MAX_TILE_PIXELS)
        return "tile area over the cap";
    return NULL;
}

static uint32_t rect_area(pt_rect t)
{
    return (t.x1 - t.x0) * (t.y1 - t.y0);
}

static pt_rect r_rect(proto_reader *r)
{
    pt_rect t;
    t.x0 = proto_r_u32(r, "tile x0");
    t.y0 = proto_r_u32(r, "tile y0");
    t.x1 = proto_r_u32(r, "tile x1");
    t.y1 = proto_r_u32(r, "tile y1");
    return t;
}

static void w_rect(proto_writer *w, pt_rect t)
{
    proto_w_u32(w, t.x0);
    proto_w_u32(w, t.y0);
    proto_w_u32(w, t.x1);
    proto_w_u32(w, t.y1);
}

/* An i32 travels as its two's complement bits; converting back this way is
 * defined for every value, unlike a cast of an unsigned out of int32's range. */
static int32_t i32_from_bits(uint32_t u)
{
    return u <= INT32_MAX ? (int32_t)u : -(int32_t)(UINT32_MAX - u) - 1;
}

static pt_status bad(pt_error *err, pt_status code, const char *what, const char *problem)
{
    return pt_error_set(err, code, "%s: %s", what, problem);
}

/* ---- HELLO ---- */

static const char *hello_problem(const proto_hello *m)
{
    if (m->role != PROTO_ROLE_WORKER && m->role != PROTO_ROLE_CLIENT)
        return "unknown role";
    return NULL;
}

pt_status proto_msg_encode_hello(proto_writer *w, const proto_hello *m, pt_error *err)
{
    size_t start = w->len;
    const char *why = hello_problem(m);
    if (!why && !str_fits(m->name, PROTO_MAX_NAME))
        why = "name over the length cap";
    if (!why && !str_fits(m->build_id, PROTO_MAX_BUILD_ID))
        why = "build id over the length cap";
    if (why)
        return bad(err, PT_ERR_ARG, "HELLO", why);
    proto_w_u16(w, m->version);
    proto_w_u8(w, m->role);
    proto_w_str(w, m->name);
    proto_w_u16(w, m->threads);
    proto_w_str(w, m->build_id);
    proto_w_u32(w, m->caps);
    return w_done(w, start, "HELLO", err);
}

pt_status proto_msg_decode_hello(const uint8_t *p, size_t len, proto_hello *out, pt_error *err)
{
    proto_reader r = proto_reader_make(p, len);
    proto_hello m;
    m.version = proto_r_u16(&r, "version");
    m.role = proto_r_u8(&r, "role");
    proto_r_str(&r, m.name, PROTO_MAX_NAME, "name");
    m.threads = proto_r_u16(&r, "threads");
    proto_r_str(&r, m.build_id, PROTO_MAX_BUILD_ID, "build id");
    m.caps = proto_r_u32(&r, "capabilities");
    pt_status st = proto_r_finish(&r, "HELLO", err);
    if (st != PT_OK)
        return st;
    const char *why = hello_problem(&m);
    if (why)
        return bad(err, PT_ERR_PROTO, "HELLO", why);
    *out = m;
    return PT_OK;
}

/* ---- CHALLENGE, AUTH ---- */

pt_status proto_msg_encode_challenge(proto_writer *w, const proto_challenge *m, pt_error *err)
{
    size_t start = w->len;
    proto_w_bytes(w, m->nonce, PROTO_NONCE_SIZE);
    return w_done(w, start, "CHALLENGE", err);
}

pt_status proto_msg_decode_challenge(const uint8_t *p, size_t len, proto_challenge *out,
                                     pt_error *err)
{
    proto_reader r = proto_reader_make(p, len);
    const uint8_t *nonce = proto_r_bytes(&r, PROTO_NONCE_SIZE, "nonce");
    pt_status st = proto_r_finish(&r, "CHALLENGE", err);
    if (st != PT_OK)
        return st;
    memcpy(out->nonce, nonce, PROTO_NONCE_SIZE);
    return PT_OK;
}

pt_status proto_msg_encode_auth(proto_writer *w, const proto_auth *m, pt_error *err)
{
    size_t start = w->len;
    proto_w_bytes(w, m->mac, PROTO_MAC_SIZE);
    proto_w_bytes(w, m->nonce, PROTO_NONCE_SIZE);
    return w_done(w, start, "AUTH", err);
}

pt_status proto_msg_decode_auth(const uint8_t *p, size_t len, proto_auth *out, pt_error *err)
{
    proto_reader r = proto_reader_make(p, len);
    const uint8_t *mac = proto_r_bytes(&r, PROTO_MAC_SIZE, "mac");
    const uint8_t *nonce = proto_r_bytes(&r, PROTO_NONCE_SIZE, "nonce");
    pt_status st = proto_r_finish(&r, "AUTH", err);
    if (st != PT_OK)
        return st;
    memcpy(out->mac, mac, PROTO_MAC_SIZE);
    memcpy(out->nonce, nonce, PROTO_NONCE_SIZE);
    return PT_OK;
}

/* ---- WELCOME ---- */

pt_status proto_msg_encode_welcome(proto_writer *w, const proto_welcome *m, pt_error *err)
{
    size_t start = w->len;
    if (!str_fits(m->build_id, PROTO_MAX_BUILD_ID))
        return bad(err, PT_ERR_ARG, "WELCOME", "build id over the length cap");
    proto_w_u64(w, m->session_id);
    proto_w_bytes(w, m->proof, PROTO_MAC_SIZE);
    proto_w_str(w, m->build_id);
    return w_done(w, start, "WELCOME", err);
}

pt_status proto_msg_decode_welcome(const uint8_t *p, size_t len, proto_welcome *out, pt_error *err)
{
    proto_reader r = proto_reader_make(p, len);
    proto_welcome m;
    m.session_id = proto_r_u64(&r, "session id");
    const uint8_t *proof = proto_r_bytes(&r, PROTO_MAC_SIZE, "proof");
    proto_r_str(&r, m.build_id, PROTO_MAX_BUILD_ID, "build id");
    pt_status st = proto_r_finish(&r, "WELCOME", err);
    if (st != PT_OK)
        return st;
    memcpy(m.proof, proof, PROTO_MAC_SIZE);
    *out = m;
    return PT_OK;
}

/* ---- ERROR ---- */

pt_status proto_msg_encode_error(proto_writer *w, const proto_error_msg *m, pt_error *err)
{
    size_t start = w->len;
    if (!str_fits(m->text, PROTO_MAX_ERROR_TEXT))
        return bad(err, PT_ERR_ARG, "ERROR", "text over the length cap");
    proto_w_u16(w, m->code);
    proto_w_str(w, m->text);
    return w_done(w, start, "ERROR", err);
}

pt_status proto_msg_decode_error(const uint8_t *p, size_t len, proto_error_msg *out, pt_error *err)
{
    proto_reader r = proto_reader_make(p, len);
    proto_error_msg m;
    m.code = proto_r_u16(&r, "code");
    proto_r_str(&r, m.text, PROTO_MAX_ERROR_TEXT, "text");
    pt_status st = proto_r_finish(&r, "ERROR", err);
    if (st != PT_OK)
        return st;
    *out = m;
    return PT_OK;
}

/* ---- WORK_REQUEST ---- */

pt_status proto_msg_encode_work_request(proto_writer *w, const proto_work_request *m, pt_error *err)
{
    size_t start = w->len;
    if (m->slots > PROTO_MAX_SLOTS)
        return bad(err, PT_ERR_ARG, "WORK_REQUEST", "slots over the cap");
    proto_w_u16(w, m->slots);
    return w_done(w, start, "WORK_REQUEST", err);
}

pt_status proto_msg_decode_work_request(const uint8_t *p, size_t len, proto_work_request *out,
                                        pt_error *err)
{
    proto_reader r = proto_reader_make(p, len);
    uint16_t slots = proto_r_u16(&r, "slots");
    pt_status st = proto_r_finish(&r, "WORK_REQUEST", err);
    if (st != PT_OK)
        return st;
    if (slots > PROTO_MAX_SLOTS)
        return bad(err, PT_ERR_PROTO, "WORK_REQUEST", "slots over the cap");
    out->slots = slots;
    return PT_OK;
}

/* ---- ENV (in SUBMIT and TASK) ---- */

void proto_env_none(proto_env *e)
{
    memset(e, 0, sizeof *e);
    e->strength = 1.0f;
}

int proto_env_any(const proto_env *e)
{
    return e->name[0] != '\0' || e->background;
}

int proto_env_same(const proto_env *a, const proto_env *b)
{
    /* Bits, not values: the image depends on the bits, and NaN never gets here. */
    return strcmp(a->name, b->name) == 0 && a->background == b->background &&
           memcmp(&a->strength, &b->strength, sizeof a->strength) == 0 &&
           memcmp(&a->rotate_deg, &b->rotate_deg, sizeof a->rotate_deg) == 0 &&
           memcmp(a->rgb, b->rgb, sizeof a->rgb) == 0;
}

/* Shape of an ENV block; NULL when fine. Written so that NaN fails too. */
static const char *env_problem(const proto_env *e)
{
    if (!(e->strength >= 0.0f) || !isfinite(e->strength))
        return "environment strength not finite and >= 0";
    if (!isfinite(e->rotate_deg))
        return "environment rotation not finite";
    if (e->background > 1)
        return "environment background flag not 0 or 1";
    for (int k = 0; k < 3; k++)
        if (!(e->rgb[k] >= 0.0f) || !isfinite(e->rgb[k]))
            return "background colour not finite and >= 0";
    if (e->background && e->name[0])
        return "a map and a uniform background are two environments";
    return NULL;
}

static void w_env(proto_writer *w, const proto_env *e)
{
    proto_w_str(w, e->name);
    proto_w_f32(w, e->strength);
    proto_w_f32(w, e->rotate_deg);
    proto_w_u8(w, e->background);
    for (int k = 0; k < 3; k++)
        proto_w_f32(w, e->rgb[k]);
}

static void r_env(proto_reader *r, proto_env *e)
{
    proto_r_str(r, e->name, PROTO_MAX_PATH, "environment map name");
    e->strength = proto_r_f32(r, "environment strength");
    e->rotate_deg = proto_r_f32(r, "environment rotation");
    e->background = proto_r_u8(r, "environment background flag");
    for (int k = 0; k < 3; k++)
        e->rgb[k] = proto_r_f32(r, "background colour");
}

/* ---- TASK ---- */

const char *proto_shutter_problem(const double shutter[2])
{
    /* Written so that NaN fails too. */
    if (!(shutter[0] >= 0.0 && shutter[0] <= shutter[1] && shutter[1] <= PROTO_MAX_SHUTTER_S))
        return "shutter not 0 <= open <= close <= 3600 s";
    return NULL;
}

const char *proto_clamp_problem(const float clamp[2])
{
    /* Written so that NaN fails too. */
    for (int k = 0; k < 2; k++)
        if (!(clamp[k] >= 0.0f && clamp[k] <= PROTO_MAX_CLAMP))
            return k == 0 ? "clamp direct not finite and in [0, 1e30]"
                          : "clamp indirect not finite and in [0, 1e30]";
    return NULL;
}

static const char *task_problem(const proto_task *m)
{
    const char *why = rect_problem(m->tile);
    if (why)
        return why;
    if (m->tile.x1 > m->width || m->tile.y1 > m->height)
        return "tile outside the image";
    if (m->s0 >= m->s1)
        return "sample range s0 >= s1";
    if (m->film_flags & ~PROTO_FILM_KNOWN)
        return "unknown film flags";
    if (m->animate > 1)
        return "animate flag not 0 or 1";
    /* Written so that NaN fails too. */
    if (!(m->time >= 0.0) || !isfinite(m->time) || (!m->animate && m->time != 0.0))
        return "time not finite and >= 0 (0 for a still)";
    why = proto_shutter_problem(m->shutter);
    if (!why)
        why = proto_clamp_problem(m->clamp);
    if (!why && (m->guided > PROTO_GUIDE_LAST || m->guide_pass > PROTO_MAX_GUIDE_PASS ||
                 (!m->guided && m->guide_pass != 0)))
        why = "guide flag not 0, 1 or 2, or pass over 31 (0 when not guided)";
    if (!why && !m->guided) {
        for (unsigned k = 0; k < PROTO_HASH_SIZE; k++)
            if (m->guide_hash[k])
                why = "guide hash without guiding";
    }
    return why ? why : env_problem(&m->env);
}

pt_status proto_msg_encode_task(proto_writer *w, const proto_task *m, pt_error *err)
{
    size_t start = w->len;
    const char *why = task_problem(m);
    if (!why && !str_fits(m->camera, PROTO_MAX_NAME))
        why = "camera name over the length cap";
    if (!why && !str_fits(m->variant, PROTO_MAX_NAME))
        why = "variant name over the length cap";
    if (!why && !str_fits(m->animation, PROTO_MAX_NAME))
        why = "animation name over the length cap";
    if (!why && !str_fits(m->env.name, PROTO_MAX_PATH))
        why = "environment map name over the length cap";
    if (why)
        return bad(err, PT_ERR_ARG, "TASK", why);
    proto_w_u64(w, m->job_id);
    proto_w_u64(w, m->task_id);
    w_rect(w, m->tile);
    proto_w_u32(w, m->s0);
    proto_w_u32(w, m->s1);
    proto_w_u32(w, m->width);
    proto_w_u32(w, m->height);
    proto_w_u32(w, m->seed);
    proto_w_u16(w, m->max_depth);
    proto_w_u16(w, m->rr_depth);
    proto_w_bytes(w, m->scene_hash, PROTO_HASH_SIZE);
    proto_w_u32(w, m->lease_ms);
    proto_w_str(w, m->camera);
    w_env(w, &m->env);
    proto_w_u32(w, m->film_flags);
    proto_w_str(w, m->variant);
    proto_w_u8(w, m->animate);
    proto_w_f64(w, m->time);
    proto_w_str(w, m->animation);
    proto_w_f64(w, m->shutter[0]);
    proto_w_f64(w, m->shutter[1]);
    proto_w_f32(w, m->clamp[0]);
    proto_w_f32(w, m->clamp[1]);
    proto_w_u8(w, m->guided);
    proto_w_u32(w, m->guide_pass);
    proto_w_bytes(w, m->guide_hash, PROTO_HASH_SIZE);
    return w_done(w, start, "TASK", err);
}

pt_status proto_msg_decode_task(const uint8_t *p, size_t len, proto_task *out, pt_error *err)
{
    proto_reader r = proto_reader_make(p, len);
    proto_task m;
    m.job_id = proto_r_u64(&r, "job id");
    m.task_id = proto_r_u64(&r, "task id");
    m.tile = r_rect(&r);
    m.s0 = proto_r_u32(&r, "s0");
    m.s1 = proto_r_u32(&r, "s1");
    m.width = proto_r_u32(&r, "width");
    m.height = proto_r_u32(&r, "height");
    m.seed = proto_r_u32(&r, "seed");
    m.max_depth = proto_r_u16(&r, "max depth");
    m.rr_depth = proto_r_u16(&r, "rr depth");
    const uint8_t *hash = proto_r_bytes(&r, PROTO_HASH_SIZE, "scene hash");
    m.lease_ms = proto_r_u32(&r, "lease");
    proto_r_str(&r, m.camera, PROTO_MAX_NAME, "camera");
    r_env(&r, &m.env);
    m.film_flags = proto_r_u32(&r, "film flags");
    proto_r_str(&r, m.variant, PROTO_MAX_NAME, "variant");
    m.animate = proto_r_u8(&r, "animate");
    m.time = proto_r_f64(&r, "time");
    proto_r_str(&r, m.animation, PROTO_MAX_NAME, "animation");
    m.shutter[0] = proto_r_f64(&r, "shutter open");
    m.shutter[1] = proto_r_f64(&r, "shutter close");
    m.clamp[0] = proto_r_f32(&r, "clamp direct");
    m.clamp[1] = proto_r_f32(&r, "clamp indirect");
    m.guided = proto_r_u8(&r, "guided");
    m.guide_pass = proto_r_u32(&r, "guide pass");
    const uint8_t *ghash = proto_r_bytes(&r, PROTO_HASH_SIZE, "guide hash");
    pt_status st = proto_r_finish(&r, "TASK", err);
    if (st != PT_OK)
        return st;
    memcpy(m.scene_hash, hash, PROTO_HASH_SIZE);
    memcpy(m.guide_hash, ghash, PROTO_HASH_SIZE);
    const char *why = task_problem(&m);
    if (why)
        return bad(err, PT_ERR_PROTO, "TASK", why);
    *out = m;
    return PT_OK;
}

/* ---- SCENE_GET, SCENE_CHUNK ---- */

pt_status proto_msg_encode_scene_get(proto_writer *w, const proto_scene_get *m, pt_error *err)
{
    size_t start = w->len;
    proto_w_bytes(w, m->hash, PROTO_HASH_SIZE);
    proto_w_u64(w, m->offset);
    return w_done(w, start, "SCENE_GET", err);
}

pt_status proto_msg_decode_scene_get(const uint8_t *p, size_t len, proto_scene_get *out,
                                     pt_error *err)
{
    proto_reader r = proto_reader_make(p, len);
    const uint8_t *hash = proto_r_bytes(&r, PROTO_HASH_SIZE, "scene hash");
    uint64_t offset = proto_r_u64(&r, "offset");
    pt_status st = proto_r_finish(&r, "SCENE_GET", err);
    if (st != PT_OK)
        return st;
    memcpy(out->hash, hash, PROTO_HASH_SIZE);
    out->offset = offset;
    return PT_OK;
}

static const char *chunk_problem(const proto_scene_chunk *m)
{
    if (m->len > PROTO_MAX_SCENE_CHUNK)
        return "data length over the cap";
    /* offset + len <= total, written so that it cannot wrap. */
    if (m->offset > m->total || m->len > m->total - m->offset)
        return "chunk past the end of the scene";
    return NULL;
}

pt_status proto_msg_encode_scene_chunk(proto_writer *w, const proto_scene_chunk *m, pt_error *err)
{
    size_t start = w->len;
    const char *why = chunk_problem(m);
    if (why)
        return bad(err, PT_ERR_ARG, "SCENE_CHUNK", why);
    proto_w_bytes(w, m->hash, PROTO_HASH_SIZE);
    proto_w_u64(w, m->offset);
    proto_w_u64(w, m->total);
    proto_w_u32(w, m->len);
    proto_w_bytes(w, m->data, m->len);
    return w_done(w, start, "SCENE_CHUNK", err);
}

pt_status proto_msg_decode_scene_chunk(const uint8_t *p, size_t len, proto_scene_chunk *out,
                                       pt_error *err)
{
    proto_reader r = proto_reader_make(p, len);
    proto_scene_chunk m;
    const uint8_t *hash = proto_r_bytes(&r, PROTO_HASH_SIZE, "scene hash");
    m.offset = proto_r_u64(&r, "offset");
    m.total = proto_r_u64(&r, "total size");
    m.len = proto_r_u32(&r, "data length");
    m.data = NULL;
    /* The cap is judged before the length is used to read. */
    if (r.status == PT_OK && m.len > PROTO_MAX_SCENE_CHUNK)
        proto_r_fail(&r, PT_ERR_PROTO, "over the cap:", "data length");
    m.data = proto_r_bytes(&r, m.len, "data");
    pt_status st = proto_r_finish(&r, "SCENE_CHUNK", err);
    if (st != PT_OK)
        return st;
    memcpy(m.hash, hash, PROTO_HASH_SIZE);
    const char *why = chunk_problem(&m);
    if (why)
        return bad(err, PT_ERR_PROTO, "SCENE_CHUNK", why);
    *out = m;
    return PT_OK;
}

/* ---- RESULT ---- */

static const char *result_problem(const proto_result *m)
{
    const char *why = rect_problem(m->tile);
    if (why)
        return why;
    if (m->s0 >= m->s1)
        return "sample range s0 >= s1";
    if (m->npixels != rect_area(m->tile))
        return "pixel count differs from the tile's area";
    return NULL;
}

/* The guiding statistics' shape (PROTO_RESULT_GUIDE): counts within the
 * guide's sizes, nodes strictly ascending and in range, values above 0. */
static const char *guide_problem(uint32_t nsnode, uint32_t nqnode, uint32_t nc, uint32_t ns,
                                 const proto_guide_entry *e)
{
    if (nsnode == 0 || nqnode == 0 || nsnode > PROTO_MAX_GUIDE_NODES ||
        nqnode > PROTO_MAX_GUIDE_NODES)
        return "guide sizes out of range";
    if (nc > nsnode || ns > nqnode)
        return "more guiding entries than the guide has nodes";
    for (uint32_t i = 0; e && i < nc + ns; i++) {
        uint32_t lim = i < nc ? nsnode : nqnode;
        if (e[i].node >= lim || e[i].value == 0 ||
            (i != 0 && i != nc && e[i].node <= e[i - 1].node))
            return "guiding entries not ascending, in range and above 0";
    }
    return NULL;
}

/* The pixel's count and hits, checked as the decoder checks them. */
static const char *result_pixel_problem(uint32_t n, uint32_t hits, uint32_t nmax)
{
    if (n > nmax)
        return "sample count over s1 - s0";
    if (hits > n)
        return "camera hits over the sample count";
    return NULL;
}

/* A pixel's pass sums need 128 bits (any of them). */
static int pass_wide(const pt_pass_acc *a)
{
    int wide = 0;
    for (int k = 0; k < PT_PASS_SUMS; k++)
        wide |= a->s[k] != (pt_i128)(int64_t)a->s[k];
    for (int k = 0; k < PT_PASS_SQS; k++)
        wide |= a->sq[k] > UINT64_MAX;
    return wide;
}

/* One pixel's pass sums at q, 8 or 16 bytes each (wide), then n_even. */
static void put_pass(uint8_t *q, const pt_pass_acc *a, int wide)
{
    size_t step = wide ? 16 : 8;
    for (int k = 0; k < PT_PASS_SUMS; k++, q += step) {
        proto_put_u64(q, (uint64_t)a->s[k]);
        if (wide)
            proto_put_u64(q + 8, (uint64_t)(a->s[k] >> 64));
    }
    for (int k = 0; k < PT_PASS_SQS; k++, q += step) {
        proto_put_u64(q, (uint64_t)a->sq[k]);
        if (wide)
            proto_put_u64(q + 8, (uint64_t)(a->sq[k] >> 64));
    }
    proto_put_u32(q, a->n_even);
    q += 4;
    for (int k = 0; k < PT_CRYPTO_KINDS; k++, q += 8 * PT_CRYPTO_KEEP)
        for (int j = 0; j < PT_CRYPTO_KEEP; j++) {
            proto_put_u32(q + 4 * j, a->cid[k][j]);
            proto_put_u32(q + 4 * (PT_CRYPTO_KEEP + j), a->ccnt[k][j]);
        }
}

static void get_pass(const uint8_t *q, pt_pass_acc *a, int wide)
{
    size_t step = wide ? 16 : 8;
    for (int k = 0; k < PT_PASS_SUMS; k++, q += step)
        a->s[k] = wide ? (pt_i128)(((pt_u128)proto_get_u64(q + 8) << 64) | proto_get_u64(q))
                       : (pt_i128)(int64_t)proto_get_u64(q);
    for (int k = 0; k < PT_PASS_SQS; k++, q += step) {
        a->sq[k] = proto_get_u64(q);
        if (wide)
            a->sq[k] |= (pt_u128)proto_get_u64(q + 8) << 64;
    }
    a->n_even = proto_get_u32(q);
    a->pad = 0;
    q += 4;
    for (int k = 0; k < PT_CRYPTO_KINDS; k++, q += 8 * PT_CRYPTO_KEEP)
        for (int j = 0; j < PT_CRYPTO_KEEP; j++) {
            a->cid[k][j] = proto_get_u32(q + 4 * j);
            a->ccnt[k][j] = proto_get_u32(q + 4 * (PT_CRYPTO_KEEP + j));
        }
}

/* The pass sums' own checks against their pixel's n; NULL when sound. */
static const char *pass_problem(const pt_pass_acc *a, uint32_t n)
{
    if (a->n_even > n)
        return "even count over n";
    for (int k = 0; k < PT_CRYPTO_KINDS; k++)
        if (!pt_crypto_canonical(a->cid[k], a->ccnt[k], n))
            return "Cryptomatte ids not in canonical form";
    return NULL;
}

pt_status proto_msg_encode_result(proto_writer *w, const proto_result *m, pt_error *err)
{
    size_t start = w->len;
    const char *why = result_problem(m);
    if (!why && m->guide)
        why = guide_problem(m->g_nsnode, m->g_nqnode, m->gcount, m->gsum, m->guide);
    if (why)
        return bad(err, PT_ERR_ARG, "RESULT", why);
    uint32_t nmax = m->s1 - m->s0;
    for (uint32_t i = 0; i < m->npixels; i++)
        if ((why = result_pixel_problem(m->pixels[i].n, m->pixels[i].hits, nmax)) != NULL ||
            (m->pass && (why = pass_problem(&m->pass[i], m->pixels[i].n)) != NULL))
            return pt_error_set(err, PT_ERR_ARG, "RESULT: pixel %u %s", (unsigned)i, why);
    proto_w_u64(w, m->job_id);
    proto_w_u64(w, m->task_id);
    w_rect(w, m->tile);
    proto_w_u32(w, m->s0);
    proto_w_u32(w, m->s1);
    proto_w_u64(w, m->rejected);
    proto_w_u64(w, m->rays);
    proto_w_u64(w, m->capped);
    proto_w_u32(w, m->npixels);
    /* Each kind of sum narrow (8 bytes) when it fits 64 bits in every pixel
     * (the usual case), so that a pixel is 40 bytes on the wire. */
    int wide_rgb = 0, wide_sq = 0;
    for (uint32_t i = 0; i < m->npixels; i++) {
        const pt_pixel_acc *a = &m->pixels[i];
        for (int c = 0; c < 3; c++)
            wide_rgb |= a->fsum[c] != (pt_i128)(int64_t)a->fsum[c];
        wide_sq |= a->fsum_sq > UINT64_MAX;
    }
    int wide_pass = 0;
    for (uint32_t i = 0; m->pass && i < m->npixels; i++)
        wide_pass |= pass_wide(&m->pass[i]);
    proto_w_u8(
        w,
        (uint8_t)(wide_rgb * PROTO_RESULT_WIDE_RGB + wide_sq * PROTO_RESULT_WIDE_SQ +
                  (m->pass ? PROTO_RESULT_PASSES : 0u) + wide_pass * PROTO_RESULT_WIDE_PASSES +
                  (m->guide ? PROTO_RESULT_GUIDE : 0u) + (m->clamped ? PROTO_RESULT_CLAMPED : 0u)));
    size_t rgb = wide_rgb ? 16 : 8, sq = wide_sq ? 16 : 8, psize = 3 * rgb + sq + 8;
    /* One reservation for all pixels: a 64k-pixel tile is 2.6 MB narrow. */
    uint8_t *q = proto_w_reserve(w, (size_t)m->npixels * psize);
    if (!q)
        return w_done(w, start, "RESULT", err);
    for (uint32_t i = 0; i < m->npixels; i++, q += psize) {
        const pt_pixel_acc *a = &m->pixels[i];
        for (int c = 0; c < 3; c++) {
            proto_put_u64(q + rgb * c, (uint64_t)a->fsum[c]);
            if (wide_rgb)
                proto_put_u64(q + rgb * c + 8, (uint64_t)(a->fsum[c] >> 64));
        }
        proto_put_u64(q + 3 * rgb, (uint64_t)a->fsum_sq);
        if (wide_sq)
            proto_put_u64(q + 3 * rgb + 8, (uint64_t)(a->fsum_sq >> 64));
        proto_put_u32(q + psize - 8, a->n);
        proto_put_u32(q + psize - 4, a->hits);
    }
    if (m->pass) {
        size_t qsize = wide_pass ? PROTO_RESULT_WIDE_PASS_SIZE : PROTO_RESULT_PASS_SIZE;
        if (!(q = proto_w_reserve(w, (size_t)m->npixels * qsize)))
            return w_done(w, start, "RESULT", err);
        for (uint32_t i = 0; i < m->npixels; i++, q += qsize)
            put_pass(q, &m->pass[i], wide_pass);
    }
    if (m->clamped)
        proto_w_u64(w, m->clamped);
    if (m->guide) {
        proto_w_u32(w, m->g_nsnode);
        proto_w_u32(w, m->g_nqnode);
        proto_w_u32(w, m->gcount);
        proto_w_u32(w, m->gsum);
        for (uint32_t i = 0; i < m->gcount + m->gsum; i++) {
            proto_w_u32(w, m->guide[i].node);
            proto_w_u64(w, m->guide[i].value);
        }
    }
    return w_done(w, start, "RESULT", err);
}

/* The guiding statistics at r (GUIDE's layout) into out: the entries in an
 * allocation of their own. */
static pt_status decode_guide(proto_reader *r, proto_result *m, pt_error *err)
{
    if (proto_r_left(r) < 16)
        return pt_error_set(err, PT_ERR_PROTO, "RESULT: truncated guiding statistics");
    m->g_nsnode = proto_r_u32(r, "guide spatial nodes");
    m->g_nqnode = proto_r_u32(r, "guide directional nodes");
    m->gcount = proto_r_u32(r, "guiding counts");
    m->gsum = proto_r_u32(r, "guiding sums");
    const char *why = guide_problem(m->g_nsnode, m->g_nqnode, m->gcount, m->gsum, NULL);
    if (why)
        return bad(err, PT_ERR_PROTO, "RESULT", why);
    uint64_t n = (uint64_t)m->gcount + m->gsum;
    if (proto_r_left(r) != n * 12)
        return pt_error_set(err, PT_ERR_PROTO,
                            "RESULT: guiding statistics of %llu entries in %zu bytes",
                            (unsigned long long)n, proto_r_left(r));
    /* One entry at least, so an empty list is an allocation too. */
    proto_guide_entry *e = pt_malloc_array(n ? (size_t)n : 1, sizeof *e);
    if (!e)
        return pt_error_set(err, PT_ERR_NOMEM, "RESULT: %llu guiding entries",
                            (unsigned long long)n);
    for (uint64_t i = 0; i < n; i++) {
        e[i].node = proto_r_u32(r, "guide node");
        e[i].value = proto_r_u64(r, "guide value");
    }
    if ((why = guide_problem(m->g_nsnode, m->g_nqnode, m->gcount, m->gsum, e)) != NULL) {
        pt_free(e);
        return bad(err, PT_ERR_PROTO, "RESULT", why);
    }
    m->guide = e;
    m->owns_guide = 1;
    return PT_OK;
}

pt_status proto_msg_decode_result(const uint8_t *p, size_t len, pt_pixel_acc *buf, size_t buf_cap,
                                  proto_result *out, pt_error *err)
{
    proto_reader r = proto_reader_make(p, len);
    proto_result m;
    m.job_id = proto_r_u64(&r, "job id");
    m.task_id = proto_r_u64(&r, "task id");
    m.tile = r_rect(&r);
    m.s0 = proto_r_u32(&r, "s0");
    m.s1 = proto_r_u32(&r, "s1");
    m.rejected = proto_r_u64(&r, "rejected");
    m.rays = proto_r_u64(&r, "rays");
    m.capped = proto_r_u64(&r, "paths capped");
    m.clamped = 0;
    m.npixels = proto_r_u32(&r, "pixel count");
    uint8_t form = proto_r_u8(&r, "pixel form");
    m.pixels = NULL;
    m.owns_pixels = 0;
    m.pass = NULL;
    m.guide = NULL;
    m.owns_guide = 0;
    m.g_nsnode = m.g_nqnode = m.gcount = m.gsum = 0;
    if (r.status != PT_OK)
        return proto_r_finish(&r, "RESULT", err);
    /* Everything about the count is settled before a byte is allocated: the
     * tile's shape and cap, that the count is its area, and that exactly that
     * many pixels are present. */
    const char *why = result_problem(&m);
    if (why)
        return bad(err, PT_ERR_PROTO, "RESULT", why);
    if (form & ~(PROTO_RESULT_WIDE_RGB | PROTO_RESULT_WIDE_SQ | PROTO_RESULT_PASSES |
                 PROTO_RESULT_WIDE_PASSES | PROTO_RESULT_GUIDE | PROTO_RESULT_CLAMPED) ||
        ((form & PROTO_RESULT_WIDE_PASSES) && !(form & PROTO_RESULT_PASSES)))
        return bad(err, PT_ERR_PROTO, "RESULT", "unknown pixel form");
    int wide_rgb = (form & PROTO_RESULT_WIDE_RGB) != 0,
        wide_sq = (form & PROTO_RESULT_WIDE_SQ) != 0, passes = (form & PROTO_RESULT_PASSES) != 0,
        wide_pass = (form & PROTO_RESULT_WIDE_PASSES) != 0;
    size_t rgb = wide_rgb ? 16 : 8, psize = 3 * rgb + (wide_sq ? 16 : 8) + 8;
    size_t qsize = !passes ? 0 : wide_pass ? PROTO_RESULT_WIDE_PASS_SIZE : PROTO_RESULT_PASS_SIZE;
    size_t body = (size_t)m.npixels * (psize + qsize) + ((form & PROTO_RESULT_CLAMPED) ? 8 : 0);
    if (proto_r_left(&r) < body)
        return pt_error_set(err, PT_ERR_PROTO, "RESULT: truncated pixels (%zu of %zu bytes)",
                            proto_r_left(&r), body);
    if (proto_r_left(&r) > body && !(form & PROTO_RESULT_GUIDE))
        return pt_error_set(err, PT_ERR_PROTO, "RESULT: %zu trailing bytes",
                            proto_r_left(&r) - body);
    const uint8_t *q = r.p;
    uint32_t nmax = m.s1 - m.s0;
    for (uint32_t i = 0; i < m.npixels; i++) {
        const uint8_t *pq = q + (size_t)i * psize + psize - 8;
        why = result_pixel_problem(proto_get_u32(pq), proto_get_u32(pq + 4), nmax);
        if (why)
            return pt_error_set(err, PT_ERR_PROTO, "RESULT: pixel %u %s", (unsigned)i, why);
    }
    pt_pixel_acc *px = buf;
    if (passes) {
        /* The pixels then their passes, in one block (proto_result.pass). */
        size_t each = sizeof *px + sizeof *m.pass;
        px = pt_malloc_array(m.npixels, each);
        if (!px)
            return pt_error_set(err, PT_ERR_NOMEM, "RESULT: %u pixels with passes",
                                (unsigned)m.npixels);
        m.owns_pixels = 1;
        m.pass = (pt_pass_acc *)(px + m.npixels);
    } else if (buf) {
        if (m.npixels > buf_cap)
            return pt_error_set(err, PT_ERR_LIMIT, "RESULT: %u pixels, buffer holds %zu",
                                (unsigned)m.npixels, buf_cap);
    } else {
        px = pt_malloc_array(m.npixels, sizeof *px);
        if (!px)
            return pt_error_set(err, PT_ERR_NOMEM, "RESULT: %u pixels", (unsigned)m.npixels);
        m.owns_pixels = 1;
    }
    int need_rgb = 0, need_sq = 0;
    for (uint32_t i = 0; i < m.npixels; i++, q += psize) {
        for (int c = 0; c < 3; c++)
            px[i].fsum[c] = wide_rgb ? (pt_i128)(((pt_u128)proto_get_u64(q + 16 * c + 8) << 64) |
                                                 proto_get_u64(q + 16 * c))
                                     : (pt_i128)(int64_t)proto_get_u64(q + 8 * c);
        px[i].fsum_sq = proto_get_u64(q + 3 * rgb);
        if (wide_sq)
            px[i].fsum_sq |= (pt_u128)proto_get_u64(q + 3 * rgb + 8) << 64;
        px[i].n = proto_get_u32(q + psize - 8);
        px[i].hits = proto_get_u32(q + psize - 4);
        for (int c = 0; c < 3; c++)
            need_rgb |= px[i].fsum[c] != (pt_i128)(int64_t)px[i].fsum[c];
        need_sq |= px[i].fsum_sq > UINT64_MAX;
    }
    int need_pass = 0;
    for (uint32_t i = 0; passes && i < m.npixels; i++, q += qsize) {
        get_pass(q, &m.pass[i], wide_pass);
        need_pass |= pass_wide(&m.pass[i]);
        if ((why = pass_problem(&m.pass[i], px[i].n)) != NULL) {
            pt_free(px);
            return pt_error_set(err, PT_ERR_PROTO, "RESULT: pixel %u %s", (unsigned)i, why);
        }
    }
    /* One encoding per message (the encoder's): a wide kind that no pixel
     * needs is refused, so a RESULT's bytes, which the results log keeps and
     * verification compares, are a function of its values. */
    if (wide_rgb > need_rgb || wide_sq > need_sq || wide_pass > need_pass) {
        if (m.owns_pixels)
            pt_free(px);
        return bad(err, PT_ERR_PROTO, "RESULT", "a wide pixel form that no pixel needs");
    }
    if (form & PROTO_RESULT_CLAMPED) {
        /* The count after the pixels and passes; never 0, so that a RESULT's
         * bytes are a function of its values. */
        m.clamped = proto_get_u64(q);
        if (m.clamped == 0) {
            if (m.owns_pixels)
                pt_free(px);
            return bad(err, PT_ERR_PROTO, "RESULT", "a clamped count of 0");
        }
    }
    if (form & PROTO_RESULT_GUIDE) {
        /* The statistics after the pixels (GUIDE's layout, above). */
        proto_reader gr = proto_reader_make(r.p + body, proto_r_left(&r) - body);
        pt_status gst = decode_guide(&gr, &m, err);
        if (gst != PT_OK) {
            if (m.owns_pixels)
                pt_free(px);
            return gst;
        }
    }
    m.pixels = px;
    *out = m;
    return PT_OK;
}

void proto_result_fini(proto_result *r)
{
    if (!r)
        return;
    if (r->owns_pixels)
        pt_free(r->pixels);
    if (r->owns_guide)
        pt_free(r->guide);
    r->guide = NULL;
    r->owns_guide = 0;
    r->pixels = NULL;
    r->pass = NULL;
    r->owns_pixels = 0;
}

/* ---- DENOISE_TASK, DENOISE_RESULT ---- */

/* Shape of a region: non-empty, ordered, each side within the cap (so its
 * area, at most 2^20, fits 32 bits). NULL when fine. */
static const char *region_problem(pt_rect t)
{
    if (t.x0 >= t.x1)
        return "region x0 >= x1";
    if (t.y0 >= t.y1)
        return "region y0 >= y1";
    if (t.x1 - t.x0 > PROTO_MAX_DENOISE_REGION || t.y1 - t.y0 > PROTO_MAX_DENOISE_REGION)
        return "region side over the cap";
    return NULL;
}

static const char *denoise_task_problem(const proto_denoise_task *m)
{
    if (!(m->task_id & PROTO_DENOISE_TASK_BIT))
        return "task id without the denoise bit";
    if (m->crop_w == 0 || m->crop_h == 0 || m->crop_w > PROTO_MAX_DENOISE_CROP ||
        m->crop_h > PROTO_MAX_DENOISE_CROP)
        return "crop width or height not in [1, 1280]";
    const char *why = region_problem(m->region);
    if (why)
        return why;
    if (m->region.x1 > m->crop_w || m->region.y1 > m->crop_h)
        return "region outside the crop";
    /* Written so that NaN fails too. */
    if (!(m->despeckle == 0.0f || (m->despeckle >= 1.0f && m->despeckle <= PROTO_MAX_DESPECKLE)))
        return "despeckle not 0 or in [1, 1e6]";
    if (m->size != (uint64_t)m->crop_w * m->crop_h * PROTO_DENOISE_PLANES * 4)
        return "input size not crop width x height x 20 planes x 4";
    return NULL;
}

pt_status proto_msg_encode_denoise_task(proto_writer *w, const proto_denoise_task *m, pt_error *err)
{
    size_t start = w->len;
    const char *why = denoise_task_problem(m);
    if (why)
        return bad(err, PT_ERR_ARG, "DENOISE_TASK", why);
    proto_w_u64(w, m->job_id);
    proto_w_u64(w, m->task_id);
    proto_w_u32(w, m->crop_w);
    proto_w_u32(w, m->crop_h);
    w_rect(w, m->region);
    proto_w_f32(w, m->despeckle);
    proto_w_u32(w, m->lease_ms);
    proto_w_bytes(w, m->hash, PROTO_HASH_SIZE);
    proto_w_u64(w, m->size);
    return w_done(w, start, "DENOISE_TASK", err);
}

pt_status proto_msg_decode_denoise_task(const uint8_t *p, size_t len, proto_denoise_task *out,
                                        pt_error *err)
{
    proto_reader r = proto_reader_make(p, len);
    proto_denoise_task m;
    m.job_id = proto_r_u64(&r, "job id");
    m.task_id = proto_r_u64(&r, "task id");
    m.crop_w = proto_r_u32(&r, "crop width");
    m.crop_h = proto_r_u32(&r, "crop height");
    m.region = r_rect(&r);
    m.despeckle = proto_r_f32(&r, "despeckle");
    m.lease_ms = proto_r_u32(&r, "lease");
    const uint8_t *hash = proto_r_bytes(&r, PROTO_HASH_SIZE, "input hash");
    m.size = proto_r_u64(&r, "input size");
    pt_status st = proto_r_finish(&r, "DENOISE_TASK", err);
    if (st != PT_OK)
        return st;
    memcpy(m.hash, hash, PROTO_HASH_SIZE);
    const char *why = denoise_task_problem(&m);
    if (why)
        return bad(err, PT_ERR_PROTO, "DENOISE_TASK", why);
    *out = m;
    return PT_OK;
}

static const char *denoise_result_problem(const proto_denoise_result *m)
{
    if (!(m->task_id & PROTO_DENOISE_TASK_BIT))
        return "task id without the denoise bit";
    const char *why = region_problem(m->region);
    if (why)
        return why;
    if (m->npixels != rect_area(m->region))
        return "pixel count differs from the region's area";
    return NULL;
}

pt_status proto_msg_encode_denoise_result(proto_writer *w, const proto_denoise_result *m,
                                          pt_error *err)
{
    size_t start = w->len;
    const char *why = denoise_result_problem(m);
    if (why)
        return bad(err, PT_ERR_ARG, "DENOISE_RESULT", why);
    proto_w_u64(w, m->job_id);
    proto_w_u64(w, m->task_id);
    w_rect(w, m->region);
    proto_w_u32(w, m->npixels);
    /* The caller's bytes are the planes already little-endian. */
    proto_w_bytes(w, m->data, (size_t)m->npixels * 12);
    return w_done(w, start, "DENOISE_RESULT", err);
}

pt_status proto_msg_decode_denoise_result(const uint8_t *p, size_t len, proto_denoise_result *out,
                                          pt_error *err)
{
    proto_reader r = proto_reader_make(p, len);
    proto_denoise_result m;
    m.job_id = proto_r_u64(&r, "job id");
    m.task_id = proto_r_u64(&r, "task id");
    m.region = r_rect(&r);
    m.npixels = proto_r_u32(&r, "pixel count");
    m.data = NULL;
    if (r.status != PT_OK)
        return proto_r_finish(&r, "DENOISE_RESULT", err);
    /* The count is settled (the region's area, at most 2^20) before it is
     * used as a length. */
    const char *why = denoise_result_problem(&m);
    if (why)
        return bad(err, PT_ERR_PROTO, "DENOISE_RESULT", why);
    m.data = proto_r_bytes(&r, (size_t)m.npixels * 12, "pixels");
    pt_status st = proto_r_finish(&r, "DENOISE_RESULT", err);
    if (st != PT_OK)
        return st;
    *out = m;
    return PT_OK;
}

/* ---- HEARTBEAT ---- */

pt_status proto_msg_encode_heartbeat(proto_writer *w, const proto_heartbeat *m, pt_error *err)
{
    size_t start = w->len;
    if (m->count > PROTO_MAX_HEARTBEAT_TASKS)
        return bad(err, PT_ERR_ARG, "HEARTBEAT", "task count over the cap");
    proto_w_u16(w, m->count);
    for (uint16_t i = 0; i < m->count; i++)
        proto_w_u64(w, m->task_ids[i]);
    return w_done(w, start, "HEARTBEAT", err);
}

pt_status proto_msg_decode_heartbeat(const uint8_t *p, size_t len, proto_heartbeat *out,
                                     pt_error *err)
{
    proto_reader r = proto_reader_make(p, len);
    uint16_t count = proto_r_u16(&r, "task count");
    if (r.status == PT_OK && count > PROTO_MAX_HEARTBEAT_TASKS)
        proto_r_fail(&r, PT_ERR_PROTO, "over the cap:", "task count");
    /* Ids are read straight into out only after the whole payload checked
     * out, so a failure leaves out untouched. */
    const uint8_t *ids = proto_r_bytes(&r, (size_t)count * 8, "task ids");
    pt_status st = proto_r_finish(&r, "HEARTBEAT", err);
    if (st != PT_OK)
        return st;
    out->count = count;
    for (uint16_t i = 0; i < count; i++)
        out->task_ids[i] = proto_get_u64(ids + (size_t)i * 8);
    return PT_OK;
}

/* ---- JOB_REF (STATUS, WATCH, CANCEL, FETCH, SUBMITTED) ---- */

pt_status proto_msg_encode_job_ref(proto_writer *w, const proto_job_ref *m, pt_error *err)
{
    size_t start = w->len;
    proto_w_u64(w, m->job_id);
    return w_done(w, start, "JOB_REF", err);
}

pt_status proto_msg_decode_job_ref(const uint8_t *p, size_t len, proto_job_ref *out, pt_error *err)
{
    proto_reader r = proto_reader_make(p, len);
    uint64_t id = proto_r_u64(&r, "job id");
    pt_status st = proto_r_finish(&r, "JOB_REF", err);
    if (st != PT_OK)
        return st;
    out->job_id = id;
    return PT_OK;
}

/* ---- FETCH_FRAME ---- */

pt_status proto_msg_encode_fetch_frame(proto_writer *w, const proto_fetch_frame *m, pt_error *err)
{
    size_t start = w->len;
    proto_w_u64(w, m->job_id);
    proto_w_u32(w, m->frame);
    return w_done(w, start, "FETCH_FRAME", err);
}

pt_status proto_msg_decode_fetch_frame(const uint8_t *p, size_t len, proto_fetch_frame *out,
                                       pt_error *err)
{
    proto_reader r = proto_reader_make(p, len);
    proto_fetch_frame m;
    m.job_id = proto_r_u64(&r, "job id");
    m.frame = proto_r_u32(&r, "frame");
    pt_status st = proto_r_finish(&r, "FETCH_FRAME", err);
    if (st != PT_OK)
        return st;
    *out = m;
    return PT_OK;
}

/* ---- SUBMIT ---- */

static const char *submit_problem(const proto_submit *m)
{
    if ((m->width == 0) != (m->height == 0))
        return "width and height must both be 0 or both be > 0";
    if (m->spp == 0)
        return "samples per pixel is 0";
    /* Written so that NaN fails too. */
    if (!(m->target_error >= 0.0) || !isfinite(m->target_error))
        return "target error not finite and >= 0";
    if (!(m->min_gain >= 0.0) || !isfinite(m->min_gain))
        return "min gain not finite and >= 0";
    if (m->bundle_size == 0)
        return "bundle size is 0";
    if (m->film_flags & ~PROTO_FILM_KNOWN)
        return "unknown film flags";
    pt_frames fr = {m->frame_first, m->frame_last, m->frame_step};
    if (pt_frames_check(&fr, NULL) != PT_OK)
        return "bad frame range";
    if (fr.step ? !(m->fps > 0.0) || !isfinite(m->fps) : m->fps != 0.0 || m->animation[0])
        return "frames per second not finite and > 0 for a range (0 and no animation for a "
               "still)";
    const char *why = proto_shutter_problem(m->shutter);
    if (!why)
        why = proto_clamp_problem(m->clamp);
    if (!why && m->guiding > PROTO_GUIDING_AUTO)
        why = "guiding mode not off (0), on (1) or auto (2)";
    return why ? why : env_problem(&m->env);
}

pt_status proto_msg_encode_submit(proto_writer *w, const proto_submit *m, pt_error *err)
{
    size_t start = w->len;
    const char *why =
        !str_fits(m->name, PROTO_MAX_NAME)        ? "name over the length cap"
        : !str_fits(m->camera, PROTO_MAX_NAME)    ? "camera name over the length cap"
        : !str_fits(m->variant, PROTO_MAX_NAME)   ? "variant name over the length cap"
        : !str_fits(m->animation, PROTO_MAX_NAME) ? "animation name over the length cap"
        : !str_fits(m->env.name, PROTO_MAX_PATH)  ? "environment map name over the length cap"
                                                  : submit_problem(m);
    if (why)
        return bad(err, PT_ERR_ARG, "SUBMIT", why);
    proto_w_str(w, m->name);
    proto_w_u32(w, m->width);
    proto_w_u32(w, m->height);
    proto_w_u32(w, m->spp);
    proto_w_u32(w, m->seed);
    proto_w_u32(w, (uint32_t)m->priority);
    proto_w_u16(w, m->max_depth);
    proto_w_u32(w, m->min_spp);
    proto_w_f64(w, m->target_error);
    proto_w_u64(w, m->bundle_size);
    proto_w_bytes(w, m->bundle_hash, PROTO_HASH_SIZE);
    proto_w_str(w, m->camera);
    proto_w_f64(w, m->min_gain);
    w_env(w, &m->env);
    proto_w_u32(w, m->film_flags);
    proto_w_str(w, m->variant);
    proto_w_u32(w, m->frame_first);
    proto_w_u32(w, m->frame_last);
    proto_w_u32(w, m->frame_step);
    proto_w_f64(w, m->fps);
    proto_w_str(w, m->animation);
    proto_w_f64(w, m->shutter[0]);
    proto_w_f64(w, m->shutter[1]);
    proto_w_f32(w, m->clamp[0]);
    proto_w_f32(w, m->clamp[1]);
    proto_w_u8(w, m->guiding);
    return w_done(w, start, "SUBMIT", err);
}

pt_status proto_msg_decode_submit(const uint8_t *p, size_t len, proto_submit *out, pt_error *err)
{
    proto_reader r = proto_reader_make(p, len);
    proto_submit m;
    proto_r_str(&r, m.name, PROTO_MAX_NAME, "name");
    m.width = proto_r_u32(&r, "width");
    m.height = proto_r_u32(&r, "height");
    m.spp = proto_r_u32(&r, "spp");
    m.seed = proto_r_u32(&r, "seed");
    m.priority = i32_from_bits(proto_r_u32(&r, "priority"));
    m.max_depth = proto_r_u16(&r, "max depth");
    m.min_spp = proto_r_u32(&r, "min spp");
    m.target_error = proto_r_f64(&r, "target error");
    m.bundle_size = proto_r_u64(&r, "bundle size");
    const uint8_t *hash = proto_r_bytes(&r, PROTO_HASH_SIZE, "bundle hash");
    proto_r_str(&r, m.camera, PROTO_MAX_NAME, "camera");
    m.min_gain = proto_r_f64(&r, "min gain");
    r_env(&r, &m.env);
    m.film_flags = proto_r_u32(&r, "film flags");
    proto_r_str(&r, m.variant, PROTO_MAX_NAME, "variant");
    m.frame_first = proto_r_u32(&r, "first frame");
    m.frame_last = proto_r_u32(&r, "last frame");
    m.frame_step = proto_r_u32(&r, "frame step");
    m.fps = proto_r_f64(&r, "frames per second");
    proto_r_str(&r, m.animation, PROTO_MAX_NAME, "animation");
    m.shutter[0] = proto_r_f64(&r, "shutter open");
    m.shutter[1] = proto_r_f64(&r, "shutter close");
    m.clamp[0] = proto_r_f32(&r, "clamp direct");
    m.clamp[1] = proto_r_f32(&r, "clamp indirect");
    m.guiding = proto_r_u8(&r, "guiding");
    pt_status st = proto_r_finish(&r, "SUBMIT", err);
    if (st != PT_OK)
        return st;
    memcpy(m.bundle_hash, hash, PROTO_HASH_SIZE);
    const char *why = submit_problem(&m);
    if (why)
        return bad(err, PT_ERR_PROTO, "SUBMIT", why);
    *out = m;
    return PT_OK;
}

/* ---- JOB_INFO, JOB_LIST ---- */

/* Bytes of a JOB_INFO with every string empty: the least an entry of
 * JOB_LIST can take, so a count is checked against the bytes present. */
#define JOB_INFO_FIXED 162u

static const char *job_info_problem(const proto_job_info *m)
{
    if (!str_fits(m->name, PROTO_MAX_NAME))
        return "name over the length cap";
    if (!str_fits(m->owner, PROTO_MAX_NAME))
        return "owner over the length cap";
    if (!str_fits(m->scene, PROTO_MAX_PATH))
        return "scene over the length cap";
    if (!str_fits(m->output, PROTO_MAX_PATH))
        return "output over the length cap";
    if (!str_fits(m->message, PROTO_MAX_ERROR_TEXT))
        return "message over the length cap";
    if (m->nshown > PROTO_MAX_FRAMES_SHOWN)
        return "frames listed over the cap";
    if (m->guided > 1 || (!m->guided && (m->guide_pass || m->guide_spp)))
        return "guiding pass of an unguided job";
    if (m->bdpt > 1)
        return "bidirectional flag not 0 or 1";
    return NULL;
}

static void w_job_info(proto_writer *w, const proto_job_info *m)
{
    proto_w_u64(w, m->job_id);
    proto_w_u8(w, m->state);
    proto_w_u32(w, (uint32_t)m->priority);
    proto_w_str(w, m->name);
    proto_w_str(w, m->owner);
    proto_w_str(w, m->scene);
    proto_w_str(w, m->output);
    proto_w_u32(w, m->width);
    proto_w_u32(w, m->height);
    proto_w_u32(w, m->spp);
    proto_w_u64(w, m->samples_done);
    proto_w_u64(w, m->samples_total);
    proto_w_u32(w, m->passes_done);
    proto_w_u32(w, m->passes);
    proto_w_u32(w, m->tiles_stopped);
    proto_w_u32(w, m->tiles);
    proto_w_u32(w, m->workers);
    proto_w_f64(w, m->seconds);
    proto_w_f64(w, m->rate);
    proto_w_f64(w, m->error);
    proto_w_u64(w, m->submitted);
    proto_w_u32(w, m->queue_pos);
    proto_w_str(w, m->message);
    proto_w_u64(w, m->capped);
    proto_w_u64(w, m->rejected);
    proto_w_u32(w, m->frame_first);
    proto_w_u32(w, m->frame_last);
    proto_w_u32(w, m->frame_step);
    proto_w_u32(w, m->frames_done);
    proto_w_u32(w, m->frames_rendering);
    proto_w_u8(w, m->nshown);
    for (uint32_t i = 0; i < m->nshown; i++) {
        proto_w_u32(w, m->shown[i].frame);
        proto_w_u64(w, m->shown[i].samples_done);
        proto_w_u64(w, m->shown[i].samples_total);
    }
    proto_w_u8(w, m->guided);
    proto_w_u32(w, m->guide_pass);
    proto_w_u32(w, m->guide_spp);
    proto_w_u64(w, m->clamped);
    proto_w_u8(w, m->bdpt);
}

/* Reads one JOB_INFO into m (which may be left half-filled on failure). */
static void r_job_info(proto_reader *r, proto_job_info *m)
{
    m->job_id = proto_r_u64(r, "job id");
    m->state = proto_r_u8(r, "state");
    m->priority = i32_from_bits(proto_r_u32(r, "priority"));
    proto_r_str(r, m->name, PROTO_MAX_NAME, "name");
    proto_r_str(r, m->owner, PROTO_MAX_NAME, "owner");
    proto_r_str(r, m->scene, PROTO_MAX_PATH, "scene");
    proto_r_str(r, m->output, PROTO_MAX_PATH, "output");
    m->width = proto_r_u32(r, "width");
    m->height = proto_r_u32(r, "height");
    m->spp = proto_r_u32(r, "spp");
    m->samples_done = proto_r_u64(r, "samples merged");
    m->samples_total = proto_r_u64(r, "samples total");
    m->passes_done = proto_r_u32(r, "passes merged");
    m->passes = proto_r_u32(r, "passes");
    m->tiles_stopped = proto_r_u32(r, "tiles stopped");
    m->tiles = proto_r_u32(r, "tiles");
    m->workers = proto_r_u32(r, "workers");
    m->seconds = proto_r_f64(r, "seconds");
    m->rate = proto_r_f64(r, "rate");
    m->error = proto_r_f64(r, "error");
    m->submitted = proto_r_u64(r, "submitted");
    m->queue_pos = proto_r_u32(r, "queue position");
    proto_r_str(r, m->message, PROTO_MAX_ERROR_TEXT, "message");
    m->capped = proto_r_u64(r, "paths capped");
    m->rejected = proto_r_u64(r, "samples rejected");
    m->frame_first = proto_r_u32(r, "first frame");
    m->frame_last = proto_r_u32(r, "last frame");
    m->frame_step = proto_r_u32(r, "frame step");
    m->frames_done = proto_r_u32(r, "frames done");
    m->frames_rendering = proto_r_u32(r, "frames rendering");
    m->nshown = proto_r_u8(r, "frames listed");
    if (r->status == PT_OK && m->nshown > PROTO_MAX_FRAMES_SHOWN)
        proto_r_fail(r, PT_ERR_PROTO, "over the cap:", "frames listed");
    for (uint32_t i = 0; i < m->nshown && r->status == PT_OK; i++) {
        m->shown[i].frame = proto_r_u32(r, "frame");
        m->shown[i].samples_done = proto_r_u64(r, "frame samples merged");
        m->shown[i].samples_total = proto_r_u64(r, "frame samples total");
    }
    m->guided = proto_r_u8(r, "guided");
    m->guide_pass = proto_r_u32(r, "guiding pass");
    m->guide_spp = proto_r_u32(r, "guiding samples");
    m->clamped = proto_r_u64(r, "contributions clamped");
    m->bdpt = proto_r_u8(r, "bidirectional");
    if (r->status == PT_OK && (m->guided > 1 || (!m->guided && (m->guide_pass || m->guide_spp))))
        proto_r_fail(r, PT_ERR_PROTO, "out of range:", "guiding");
    if (r->status == PT_OK && m->bdpt > 1)
        proto_r_fail(r, PT_ERR_PROTO, "out of range:", "bidirectional");
}

pt_status proto_msg_encode_job_info(proto_writer *w, const proto_job_info *m, pt_error *err)
{
    size_t start = w->len;
    const char *why = job_info_problem(m);
    if (why)
        return bad(err, PT_ERR_ARG, "JOB_INFO", why);
    w_job_info(w, m);
    return w_done(w, start, "JOB_INFO", err);
}

pt_status proto_msg_decode_job_info(const uint8_t *p, size_t len, proto_job_info *out,
                                    pt_error *err)
{
    proto_reader r = proto_reader_make(p, len);
    proto_job_info m;
    r_job_info(&r, &m);
    pt_status st = proto_r_finish(&r, "JOB_INFO", err);
    if (st != PT_OK)
        return st;
    *out = m;
    return PT_OK;
}

pt_status proto_msg_encode_job_list(proto_writer *w, const proto_job_info *jobs, uint32_t count,
                                    pt_error *err)
{
    size_t start = w->len;
    if (count > PROTO_MAX_JOBS)
        return bad(err, PT_ERR_ARG, "JOB_LIST", "job count over the cap");
    for (uint32_t i = 0; i < count; i++) {
        const char *why = job_info_problem(&jobs[i]);
        if (why)
            return pt_error_set(err, PT_ERR_ARG, "JOB_LIST: job %u: %s", (unsigned)i, why);
    }
    proto_w_u32(w, count);
    for (uint32_t i = 0; i < count; i++)
        w_job_info(w, &jobs[i]);
    return w_done(w, start, "JOB_LIST", err);
}

pt_status proto_msg_decode_job_list(const uint8_t *p, size_t len, proto_job_list *out,
                                    pt_error *err)
{
    proto_reader r = proto_reader_make(p, len);
    uint32_t count = proto_r_u32(&r, "job count");
    /* The count is settled before a byte is allocated: its cap, and that the
     * bytes present could hold that many entries at their smallest. */
    if (r.status == PT_OK && count > PROTO_MAX_JOBS)
        proto_r_fail(&r, PT_ERR_PROTO, "over the cap:", "job count");
    if (r.status == PT_OK && proto_r_left(&r) / JOB_INFO_FIXED < count)
        proto_r_fail(&r, PT_ERR_PROTO, "more than the bytes hold:", "job count");
    if (r.status != PT_OK)
        return proto_r_finish(&r, "JOB_LIST", err);
    proto_job_info *jobs = NULL;
    if (count > 0) {
        jobs = pt_malloc_array(count, sizeof *jobs);
        if (!jobs)
            return pt_error_set(err, PT_ERR_NOMEM, "JOB_LIST: %u jobs", (unsigned)count);
    }
    for (uint32_t i = 0; i < count && r.status == PT_OK; i++)
        r_job_info(&r, &jobs[i]);
    pt_status st = proto_r_finish(&r, "JOB_LIST", err);
    if (st != PT_OK) {
        pt_free(jobs);
        return st;
    }
    out->count = count;
    out->jobs = jobs;
    return PT_OK;
}
