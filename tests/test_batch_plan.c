/* The plan of `mrvi batch` as bytes (src/batch/plan.c), as rank 0 sends it
 * to the other MPI ranks: packed and unpacked it is the same plan, --threads
 * included, and a buffer of another format (an older magic), a truncated
 * one or one with a bad count is refused. */
#include "batch/batch.h"
#include "testlib.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

static int same_plan(const mrvi_batch_plan *a, const mrvi_batch_plan *b) {
  int ok = a->n_cases == b->n_cases && a->n_keys == b->n_keys &&
           a->n_seeds == b->n_seeds && a->command == b->command &&
           a->threads == b->threads &&
           !strcmp(a->description, b->description) &&
           !strcmp(a->source, b->source) &&
           !memcmp(&a->pert, &b->pert, sizeof a->pert);
  for (int j = 0; ok && j < a->n_keys; j++)
    ok = !strcmp(a->keys[j], b->keys[j]);
  for (long i = 0; ok && i < (long)a->n_cases * a->n_keys; i++)
    ok = !strcmp(a->values[i], b->values[i]);
  for (int c = 0; ok && c < a->n_cases; c++)
    ok = a->seed[c] == b->seed[c];
  return ok;
}

int main(void) {
  char msg[1024];
  mrvi_batch_axis axes[2];
  CHECK(mrvi_batch_axis_parse("integrator.micro_steps=1,2,5", &axes[0], msg,
                              sizeof msg) == 0,
        "axis 1: %s", msg);
  CHECK(mrvi_batch_axis_parse("integrator.macro_step=linspace(0.01,0.02,2)",
                              &axes[1], msg, sizeof msg) == 0,
        "axis 2: %s", msg);
  const mrvi_batch_perturb pert = {.velocity_std = 0.25,
                                   .control_std = 0,
                                   .position_std = 1e-3,
                                   .position_uniform = 1,
                                   .temperature = 0,
                                   .rotation_std = 0,
                                   .rotation_uniform = 0};
  mrvi_batch_plan plan;
  CHECK(mrvi_batch_plan_build(&plan, "coordinates: []\n", "in.yaml", axes, 2, 0,
                              3, MRVI_BATCH_RUN, &pert, msg, sizeof msg) == 0,
        "plan: %s", msg);
  CHECK(plan.n_cases == 18, "3 x 2 points x 3 seeds: %d cases", plan.n_cases);
  plan.threads = 3;

  char *buf = NULL;
  size_t size = 0;
  CHECK(mrvi_batch_plan_pack(&plan, &buf, &size) == 0, "pack");
  mrvi_batch_plan back;
  CHECK(mrvi_batch_plan_unpack(buf, size, &back) == 0, "unpack");
  CHECK(same_plan(&plan, &back), "unpacked plan equals the plan");
  CHECK(back.threads == 3, "--threads travels with the plan (%d)",
        back.threads);
  mrvi_batch_plan_free(&back);

  /* Refused: another format, a truncated buffer, bad counts. */
  char *bad = malloc(size);
  memcpy(bad, buf, size);
  bad[7] = '3'; /* MRVIPLN3: the format without threads */
  CHECK(mrvi_batch_plan_unpack(bad, size, &back) == MRVI_EINVAL,
        "an older plan format refused");
  CHECK(mrvi_batch_plan_unpack(buf, size - 1, &back) == MRVI_EINVAL,
        "a truncated plan refused");
  CHECK(mrvi_batch_plan_unpack(buf, 12, &back) == MRVI_EINVAL,
        "a plan cut in its header refused");
  memcpy(bad, buf, size);
  const int32_t threads = -1; /* the fifth count */
  memcpy(bad + 8 + 4 * sizeof(int32_t), &threads, sizeof threads);
  CHECK(mrvi_batch_plan_unpack(bad, size, &back) == MRVI_EINVAL,
        "a negative thread count refused");
  memcpy(bad, buf, size);
  const int32_t cases = 2000000; /* the first count */
  memcpy(bad + 8, &cases, sizeof cases);
  CHECK(mrvi_batch_plan_unpack(bad, size, &back) == MRVI_EINVAL,
        "too many cases refused");
  free(bad);
  free(buf);
  mrvi_batch_plan_free(&plan);
  mrvi_batch_axis_clear(&axes[0]);
  mrvi_batch_axis_clear(&axes[1]);
  return test_finish();
}
