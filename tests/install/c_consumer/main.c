/* Builds a database of one square patch of surfels from a callback, shades a receiver under its
 * centre through the installed C API, and checks the occlusion against the analytic form factor
 * of a square seen from its axis. Prints "c consumer: ok". */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "pbgi/pbgi.h"

#define SIDE 100 /* surfels per side of a 1 x 1 square at z = 1, facing down */

static int64_t next(void* user, pbgi_surfel* out, size_t capacity) {
  int* cursor = (int*)user;
  size_t k = 0;
  for (; k < capacity && *cursor < SIDE * SIDE; ++k, ++*cursor) {
    pbgi_surfel* s = &out[k];
    memset(s, 0, sizeof(*s));
    s->position[0] = ((float)(*cursor % SIDE) + 0.5f) / SIDE - 0.5f;
    s->position[1] = ((float)(*cursor / SIDE) + 0.5f) / SIDE - 0.5f;
    s->position[2] = 1.0f;
    s->normal[2] = -1.0f;
    s->radius = 1.0f / SIDE / sqrtf(3.14159265f);
  }
  return (int64_t)k;
}

static int rewind_source(void* user) {
  *(int*)user = 0;
  return 0;
}

int main(int argc, char** argv) {
  char path[4096];
  int cursor = 0;
  pbgi_surfel_source src;
  pbgi_build_options bo;
  pbgi_database* db = NULL;
  pbgi_shade_options so;
  pbgi_shade_receiver r;
  pbgi_shade_result out;
  double a, want;
  if (argc != 2) return 2;
  snprintf(path, sizeof(path), "%s/square.pbgi", argv[1]);
  memset(&src, 0, sizeof(src));
  src.next = next;
  src.rewind = rewind_source;
  src.user = &cursor;
  src.count = SIDE * SIDE;
  pbgi_build_options_init(&bo);
  bo.channels = PBGI_CHANNELS_OCCLUSION;
  if (pbgi_build(&src, path, &bo, NULL) != PBGI_OK ||
      pbgi_database_open(path, NULL, &db) != PBGI_OK) {
    fprintf(stderr, "c consumer: %s\n", pbgi_last_error());
    return 1;
  }
  pbgi_shade_options_init(&so);
  so.compute_radiance = 0;
  memset(&r, 0, sizeof(r));
  r.normal[2] = 1.0f;
  r.reflection[2] = 1.0f;
  if (pbgi_shade(db, &r, 1, &so, &out, NULL) != PBGI_OK) {
    fprintf(stderr, "c consumer: %s\n", pbgi_last_error());
    return 1;
  }
  pbgi_database_close(db);
  /* The form factor from a point to a parallel square of side 2a centred on its normal at
   * distance 1: four corner rectangles a x a, each (1 / 2 pi) * 2 (A / sqrt(1 + A^2))
   * atan(A / sqrt(1 + A^2)) with A = a (the rectangle-to-corner-point case). */
  a = 0.5;
  want =
      4.0 / (2.0 * 3.14159265358979) * (2.0 * a / sqrt(1.0 + a * a)) * atan(a / sqrt(1.0 + a * a));
  if (fabs(out.occlusion - want) > 0.03 * want) {
    fprintf(stderr, "c consumer: occlusion %g, analytic %g\n", out.occlusion, want);
    return 1;
  }
  printf("c consumer: ok (occlusion %.4f, analytic %.4f)\n", out.occlusion, want);
  return 0;
}
