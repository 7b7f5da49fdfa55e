/* The switch of a kernel's wide (AVX2) path, chosen at run time: each kernel keeps its own
 * mode (-1: wide where the processor has AVX2; 0: the narrow path, always), which its tests
 * set to compare the two paths' bytes. */
#ifndef PLANT_WIDE_H
#define PLANT_WIDE_H

/* Set ``*mode`` to ``requested`` (-1 or 0; other values leave it) and say whether the wide
 * path is used. */
static inline int wide_switch(int *mode, int requested)
{
    if (requested == -1 || requested == 0)
        *mode = requested;
    return *mode == -1 && __builtin_cpu_supports("avx2");
}

#endif
