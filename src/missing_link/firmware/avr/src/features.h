/* What an image holds beyond the runtime, from the board file's `features` (gen-firmware puts
 * them in board.mk's DEFS): aligned sampling and timed calls (timing.c), run-time configuration
 * and its saved record (config.c), the board's log (log.c).  A feature left out is not compiled
 * or linked: its calls from the runtime and the drivers are the empty inlines of its header. */
#ifndef J2A_FEATURES_H
#define J2A_FEATURES_H
#ifndef ML_TIMING
#define ML_TIMING 1
#endif
#ifndef ML_CONFIG
#define ML_CONFIG 1
#endif
#ifndef ML_LOG
#define ML_LOG 1
#endif
#endif
