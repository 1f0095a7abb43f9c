/* A parallel region for the C kernels of the compiled extension: `body(context, thread)` on
 * `threads` POSIX threads, the caller's thread being thread 0. Returns 0, or -1 when a thread could
 * not start (the others still run, and the caller's thread does every share that one would have
 * taken only where the body takes work from a shared counter) or a body returned nonzero. */
#ifndef SFC_THREADS_H
#define SFC_THREADS_H

#include <pthread.h>
#include <stdint.h>
#include <stdlib.h>

typedef int (*sfc_body)(void *context, int64_t thread);

typedef struct { sfc_body body; void *context; int64_t thread; int status; } sfc_worker;

static void *sfc_worker_main(void *arg) {
    sfc_worker *w = (sfc_worker *)arg;
    w->status = w->body(w->context, w->thread);
    return NULL;
}

static int sfc_parallel(int64_t threads, sfc_body body, void *context) {
    if (threads < 1) threads = 1;
    sfc_worker *workers = (sfc_worker *)calloc((size_t)threads, sizeof(sfc_worker));
    pthread_t *ids = (pthread_t *)calloc((size_t)threads, sizeof(pthread_t));
    char *started = (char *)calloc((size_t)threads, 1);
    if (!workers || !ids || !started) {
        free(workers);
        free(ids);
        free(started);
        return -1;
    }
    int status = 0;
    for (int64_t i = 0; i < threads; i++) {
        workers[i].body = body;
        workers[i].context = context;
        workers[i].thread = i;
    }
    for (int64_t i = 1; i < threads; i++) {
        started[i] = pthread_create(&ids[i], NULL, sfc_worker_main, &workers[i]) == 0;
        if (!started[i]) status = -1;
    }
    sfc_worker_main(&workers[0]);
    if (workers[0].status != 0) status = -1;
    for (int64_t i = 1; i < threads; i++) {
        if (!started[i]) continue;
        pthread_join(ids[i], NULL);
        if (workers[i].status != 0) status = -1;
    }
    free(workers);
    free(ids);
    free(started);
    return status;
}

#endif
