#include "server/app/local.h"

#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <signal.h>
#include <spawn.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "common/base/alloc.h"
#include "common/base/fsutil.h"
#include "server/log.h"

extern char **environ;

pt_status srv_local_start(srv_local *l, const srv_config *cfg, uint16_t port, pt_error *err)
{
    l->stop_ms = cfg->local_stop_ms ? cfg->local_stop_ms : SRV_DEFAULT_LOCAL_STOP_MS;
    char bin[PATH_MAX];
    if (cfg->worker_bin) {
        snprintf(bin, sizeof bin, "%s", cfg->worker_bin);
    } else {
        ssize_t n = readlink("/proc/self/exe", bin, sizeof bin - 16);
        if (n <= 0)
            return pt_error_errno(err, PT_ERR_IO, "cannot find this program's folder");
        bin[n] = '\0';
        char *slash = strrchr(bin, '/');
        snprintf(slash + 1, sizeof bin - (size_t)(slash + 1 - bin), "ptworker");
    }
    if (access(bin, X_OK) != 0)
        return pt_error_errno(err, PT_ERR_IO, "%s", bin);
    const char *tmp = getenv("TMPDIR");
    snprintf(l->cache_dir, sizeof l->cache_dir, "%s/ptserve-cache-XXXXXX",
             tmp && *tmp ? tmp : "/tmp");
    if (!mkdtemp(l->cache_dir))
        return pt_error_errno(err, PT_ERR_IO, "%s", l->cache_dir);
    uint32_t threads = cfg->worker_threads;
    if (threads == 0) {
        long cores = sysconf(_SC_NPROCESSORS_ONLN);
        threads = cores > 0 ? (uint32_t)cores / cfg->local_workers : 1;
        if (threads == 0)
            threads = 1;
    }
    l->children = pt_calloc(cfg->local_workers, sizeof *l->children);
    if (!l->children)
        return pt_error_set(err, PT_ERR_NOMEM, "out of memory");
    char server_arg[64], threads_arg[16], name_arg[32];
    snprintf(server_arg, sizeof server_arg, "127.0.0.1:%u", port);
    snprintf(threads_arg, sizeof threads_arg, "%u", threads);
    for (uint32_t i = 0; i < cfg->local_workers; i++) {
        snprintf(name_arg, sizeof name_arg, "local-%u", i + 1);
        const char *argv[16];
        int a = 0;
        argv[a++] = bin;
        argv[a++] = "--server";
        argv[a++] = server_arg;
        argv[a++] = "--threads";
        argv[a++] = threads_arg;
        argv[a++] = "--cache-dir";
        argv[a++] = l->cache_dir;
        argv[a++] = "--name";
        argv[a++] = name_arg;
        if (cfg->token_path) {
            argv[a++] = "--token-file";
            argv[a++] = cfg->token_path;
        }
        argv[a] = NULL;
        posix_spawn_file_actions_t fa;
        posix_spawn_file_actions_init(&fa);
        posix_spawn_file_actions_addopen(&fa, 1, "/dev/null", O_WRONLY, 0);
        pid_t pid;
        int rc = posix_spawn(&pid, bin, &fa, NULL, (char *const *)argv, environ);
        posix_spawn_file_actions_destroy(&fa);
        if (rc != 0) {
            errno = rc;
            return pt_error_errno(err, PT_ERR_IO, "cannot start %s", bin);
        }
        l->children[l->nchildren++] = pid;
        l->alive++;
    }
    if (!cfg->quiet)
        srv_log("started %u local workers with %u threads each", cfg->local_workers, threads);
    return PT_OK;
}

/* Collects the children that exited: waiting for each (options 0) or not
 * (WNOHANG), logging how each ended when log is set. */
static void reap(srv_local *l, int options, int log)
{
    for (uint32_t i = 0; i < l->nchildren; i++) {
        if (l->children[i] <= 0)
            continue;
        int st;
        pid_t r = waitpid(l->children[i], &st, options);
        if (r == l->children[i]) {
            if (log) {
                if (WIFEXITED(st))
                    srv_log("local worker %u exited with status %d", i + 1, WEXITSTATUS(st));
                else if (WIFSIGNALED(st))
                    srv_log("local worker %u killed by signal %d", i + 1, WTERMSIG(st));
            }
            l->children[i] = 0;
            l->alive--;
        }
    }
}

void srv_local_reap(srv_local *l, int wait_all)
{
    reap(l, wait_all ? 0 : WNOHANG, !wait_all);
}

void srv_local_stop(srv_local *l)
{
    if (l->nchildren == 0) {
        pt_free(l->children);
        l->children = NULL;
        return;
    }
    for (uint32_t i = 0; i < l->nchildren; i++)
        if (l->children[i] > 0)
            kill(l->children[i], SIGTERM);
    /* A ptworker leaves within about 3 s of SIGTERM (it finishes no task);
     * a --worker-bin that ignores it, or a child stuck in the kernel, would
     * hold this coordinator's exit forever: after l->stop_ms
     * it is killed, and the log says so. */
    for (uint32_t waited = 0; l->alive > 0 && waited < l->stop_ms; waited += 50) {
        reap(l, WNOHANG, 0);
        if (l->alive > 0)
            nanosleep(&(struct timespec){0, 50 * 1000 * 1000}, NULL);
    }
    for (uint32_t i = 0; i < l->nchildren; i++)
        if (l->children[i] > 0) {
            srv_log("local worker %u did not stop within %g s of SIGTERM; killed", i + 1,
                    l->stop_ms / 1000.0);
            kill(l->children[i], SIGKILL);
        }
    reap(l, 0, 0);
    if (l->cache_dir[0]) {
        /* The cache holds only what the workers unpacked from our bundle. */
        if (pt_remove_tree(l->cache_dir) != 0)
            srv_log("could not remove %s", l->cache_dir);
    }
    pt_free(l->children);
    l->children = NULL;
}
