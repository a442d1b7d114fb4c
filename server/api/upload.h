/*
 * upload.h - upload verification: a submitted scene checked off the loop.
 *
 * A complete upload is verified on a thread of its own, since a big scene
 * takes seconds, and at most SRV_MAX_SCENE_CHECKS at once (a check holds a
 * decoded scene: an unbounded number of them was an unbounded amount of
 * memory); the others wait, in the order they completed: its SHA-256 against the one SUBMIT
 * announced, its bundle, one load of the scene in a temporary folder (with the camera asked for, so
 * a broken scene is refused now, not by every worker), and the bundle stored
 * in the state folder under the job id reserved for it. The thread writes
 * the srv_upload's pointer to the verification pipe; the loop then hands the
 * outcome to server/api/requests.h, which queues the job or refuses it. The
 * server never opens a path a client names.
 *
 * Threads: every function here is called from the event-loop thread. The
 * verification thread touches only its srv_upload and, through
 * srv_state_save_bundle, the state folder (server/store/state.h says it may).
 */
#ifndef PT_SERVER_UPLOAD_H
#define PT_SERVER_UPLOAD_H

#include <limits.h>
#include <pthread.h>
#include <stddef.h>
#include <stdint.h>

#include "common/scene/bundle.h"
#include "protocol/msg.h"
#include "server/core.h"

/* Scene checks that run at once; a check's memory is bounded by the
 * scene caps (common/scene/scene.h), so this bounds theirs. */
#define SRV_MAX_SCENE_CHECKS 2u

struct srv_upload {
    uint64_t conn_id, job_id;
    proto_submit m;
    char part[PATH_MAX]; /* the upload's file (tmp/bundle-JOB), the check's to read and remove */
    uint8_t *data;       /* its bytes (owned), freed once wrapped in bundle */
    size_t len;
    const srv_state *state;
    char tmp[PATH_MAX];
    int wake_fd;
    pthread_t thread;
    /* the outcome */
    int ok;
    uint16_t code; /* PROTO_E_* of the refusal */
    char msg[PROTO_MAX_ERROR_TEXT + 1];
    pt_bundle *bundle;
    char scene[256]; /* the entry file's name */
    uint32_t ntris;
    float aspect;
    char look[PROTO_MAX_NAME + 1];       /* a range's view when the file has no camera
                                            (pt_anim_range_view), else "" */
    char note[PROTO_MAX_ERROR_TEXT + 1]; /* a warning the job keeps as its message, or "" */
    uint32_t guided;                     /* SUBMIT's guiding resolved against the scene */
    float guide_box[6];                  /* then the first distribution's bounds */
    srv_upload *next;
};

/* Makes the verification pipe (s->verifypipe; its read end non-blocking)
 * and adds it to the loop (srv_loop_add_fd), which then calls
 * srv_upload_collect when a check is done; each outcome whose client is
 * still connected goes to verified (the client handlers' answer). */
pt_status srv_upload_open(srv_server *s, srv_verified_fn verified, pt_error *err);

/* The file c's upload goes to as it arrives: tmp/part-ID in the state
 * folder, ID the connection's (the server names it, never the client). */
void srv_upload_part_path(const srv_server *s, const srv_conn *c, char *out, size_t n);

/* Ends c's upload: closes its file, and removes it unless srv_upload_start
 * has taken it. */
void srv_upload_drop(srv_server *s, srv_conn *c);

/* c's upload is complete: reserves the job id and starts its verification,
 * or queues it behind the SRV_MAX_SCENE_CHECKS running (c is answered now
 * only when it cannot start). */
void srv_upload_start(srv_server *s, srv_conn *c);

/* Completes each verification that is done (srv_upload_open's verified
 * answers the client); a client gone meanwhile gets nothing queued, its bundle removed. */
void srv_upload_collect(srv_server *s);

/* At exit: waits for the verifications in flight (none of them is queued)
 * and closes the pipe. */
void srv_upload_close(srv_server *s);

#endif
