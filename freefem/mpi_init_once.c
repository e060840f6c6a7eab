/* MPI_Init and MPI_Finalize made idempotent for FreeFem++-mpi (LD_PRELOAD, harness/mpi_shim.py).
 *
 * Debian's MUMPS plugins for FreeFEM (MUMPS_seq.so, MUMPS.so) initialise MPI themselves when
 * they are loaded and finalise it when they are unloaded (a static object in FreeFEM's
 * plugin/seq/MUMPS_seq.cpp). Under FreeFem++-mpi, which has already initialised MPI, OpenMPI
 * then aborts: "MPI_INIT invoked more than once". With these wrappers the second MPI_Init
 * (and the second MPI_Finalize) does nothing, so each rank can factorise its subdomain with
 * the sequential MUMPS (fill-reducing METIS ordering) instead of UMFPACK64.
 *
 * The wrappers call MPI's profiling entry points (PMPI_*, part of every MPI implementation
 * by the standard's profiling interface), so no MPI header or library is needed to build
 * this: the PMPI symbols are resolved at run time from the libmpi FreeFem++-mpi links.
 * The handful of prototypes below are the MPI standard's; 0 is MPI_SUCCESS in OpenMPI and
 * MPICH alike.
 */
int PMPI_Initialized(int *flag);
int PMPI_Finalized(int *flag);
int PMPI_Init(int *argc, char ***argv);
int PMPI_Init_thread(int *argc, char ***argv, int required, int *provided);
int PMPI_Query_thread(int *provided);
int PMPI_Finalize(void);

int MPI_Init(int *argc, char ***argv)
{
    int initialised = 0;
    PMPI_Initialized(&initialised);
    return initialised ? 0 : PMPI_Init(argc, argv);
}

int MPI_Init_thread(int *argc, char ***argv, int required, int *provided)
{
    int initialised = 0;
    PMPI_Initialized(&initialised);
    if (initialised)
        return PMPI_Query_thread(provided);
    return PMPI_Init_thread(argc, argv, required, provided);
}

int MPI_Finalize(void)
{
    int finalised = 0;
    PMPI_Finalized(&finalised);
    return finalised ? 0 : PMPI_Finalize();
}
