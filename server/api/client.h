/*
 * client.h - what the client session keeps of one client connection beside
 * its transport (srv_conn.session, made at WELCOME by the session of
 * server/api/requests.h and freed with the connection): the job it watches,
 * the image it is being sent (FETCH) and the upload it is sending (UPLOAD,
 * whose scene check server/api/upload.h runs).
 *
 * An upload goes to a file of the state folder as it arrives
 * (srv_upload_part_path), open in up_fd while up_open: memory holds no
 * upload, whatever its size or number. Its size and progress are the
 * connection's too (srv_conn.uploading, up_total, up_len), which the loop's
 * rate rule reads.
 *
 * Threads: the event-loop thread only.
 */
#ifndef PT_SERVER_API_CLIENT_H
#define PT_SERVER_API_CLIENT_H

#include <stddef.h>
#include <stdint.h>

#include "protocol/msg.h"
#include "server/net/loop.h"

typedef struct srv_client_conn {
    uint64_t watch, watch_t; /* job watched, last JOB_INFO sent */
    int fetch;               /* an EXR is being sent, read from fetch_fd as the output drains */
    int fetch_fd;            /* open (when fetch) on the image as it was at FETCH */
    size_t fetch_len, fetch_off;
    uint8_t fetch_hash[32];
    int verifying;   /* its upload is being verified (a srv_upload in flight) */
    proto_submit up; /* the SUBMIT its upload answers */
    int up_open, up_fd;
} srv_client_conn;

/* c's client state; NULL unless c is a ready client. */
static inline srv_client_conn *srv_client_of(const srv_conn *c)
{
    return c->state == SRV_C_READY && c->role == PROTO_ROLE_CLIENT ? c->session : NULL;
}

#endif
