"""The original SeqNet / NetVLAD ground-truth files (``.db``, MATLAB v5 structs) read and made into datasets.

:mod:`.matfile` checks a ``.mat`` file against its own bytes before ``scipy.io.loadmat`` reads it;
:mod:`.dbstruct` reads the ``dbStruct`` it holds and builds datasets from one or more of them.
"""

from .dbstruct import DbStruct, dataset_from_frame_lists, dataset_from_structs, read_db_struct, select_descriptors

__all__ = ["DbStruct", "dataset_from_frame_lists", "dataset_from_structs", "read_db_struct", "select_descriptors"]
